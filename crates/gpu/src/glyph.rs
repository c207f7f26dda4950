//! Landmark glyphs: the moving (source) and fixed (target) points of each landmark pair, and a line between them,
//! drawn over the 3-D view and over slices.
//!
//! Every glyph is a screen-space capsule: the pixels within `radius_px` of the projected segment [a, b] of ref space
//! (a = b for a point), with a one-pixel anti-aliased edge, coverage = clamp(radius + ½ − dist, 0, 1); points get a
//! dark rim so they stay visible on any background. Glyphs composite over the frame in instance order with
//! premultiplied "over" blending ([`GlyphRenderer::render`] loads the target, it does not clear it).
//!
//! **3-D view** ([`GlyphUniforms::for_view`]): each glyph fragment is depth-tested against the ray caster's first
//! hit at its pixel ([`RenderTarget::hit_depth`]: where the accumulated opacity reaches
//! [`crate::target::HIT_OPACITY`], or the iso-surface). Depths are compared as distances along the pixel's ray, in
//! mm: a fragment farther than the hit plus [`GlyphSettings::depth_tolerance_mm`] is *behind the surface* and drawn
//! with its opacity multiplied by [`GlyphSettings::occluded_alpha`] (0 hides it; the default keeps a ghost so that a
//! hidden landmark can still be found, as 3D Slicer does with its occluded markups).
//!
//! **Slices** ([`GlyphUniforms::for_slice`]): glyphs are cut by a slab of half-width
//! [`GlyphSettings::slab_half_mm`] around the plane and projected onto it. A point at distance d from the plane has
//! radius radius·√(1 − (d/slab)²), the cross-section of a ball: it is largest on its own slice and vanishes beyond
//! the slab; a line shows the part of the segment inside the slab.
//!
//! **Where the points go** is the caller's choice: glyphs take ref-space positions. In the deformed view the moving
//! volume appears where the forward warp d sends it, so the app draws a source point pᵢ at d(pᵢ) (≈ its target qᵢ
//! for an interpolating warp; the line then shows the residual) and, with the warp off, at pᵢ itself (the line shows
//! the displacement). [`pair_glyphs`] builds the instances of a set of pairs.
//!
//! The shader is `shaders/glyph.wgsl`; the CPU reference is [`crate::cpu_reference::composite_glyphs`].

use bytemuck::{Pod, Zeroable};
use glam::{DMat4, DVec3, Mat4, Vec3};

use crate::camera::OrbitCamera;
use crate::device::GpuContext;
use crate::error::{GpuError, Result};
use crate::shader::{BindSlot, ShaderInterface, ShaderSource, Stage, WgslConstant, layout};
use crate::slice::SlicePlane;
use crate::target::{NO_HIT_DEPTH, RenderTarget};

/// `shaders/glyph.wgsl`: `vs_glyph` + `fs_glyph`, screen-space capsules over a frame or a slice.
pub const SHADER: ShaderSource = ShaderSource {
    name: "glyph",
    path: "shaders/glyph.wgsl",
    source: include_str!("../../../shaders/glyph.wgsl"),
    entry_points: &[("vs_glyph", Stage::Vertex), ("fs_glyph", Stage::Fragment)],
};

pub const SLOT_UNIFORMS: BindSlot = BindSlot::new(0, 0, "g");
/// The first-hit depth of the frame the glyphs go over ([`RenderTarget::hit_depth`]; a placeholder for slices).
pub const SLOT_HIT_DEPTH: BindSlot = BindSlot::new(0, 1, "hit_depth_tex");

pub const INTERFACE: ShaderInterface = ShaderInterface {
    pass: "glyph",
    shader: SHADER,
    uniform_structs: &[
        layout!(GlyphUniforms {
            clip_from_ref,
            ref_from_clip,
            plane_normal_ref,
            plane_offset_mm,
            viewport_px,
            mode,
            occluded_alpha,
            depth_tolerance_mm,
            slab_half_mm,
            outline_px
        }),
        layout!(GlyphInstance { a_ref, radius_px, b_ref, kind, colour }),
    ],
    slots: &[SLOT_UNIFORMS, SLOT_HIT_DEPTH],
    constants: &[
        WgslConstant::u32("MODE_VIEW", MODE_VIEW),
        WgslConstant::u32("MODE_SLICE", MODE_SLICE),
        WgslConstant::u32("KIND_POINT", KIND_POINT),
        WgslConstant::f32("NO_HIT_DEPTH", NO_HIT_DEPTH),
    ],
};

/// `GlyphUniforms::mode`: the 3-D view, depth-tested against the first hit.
pub const MODE_VIEW: u32 = 0;
/// `GlyphUniforms::mode`: a slice (slab cut, no depth test).
pub const MODE_SLICE: u32 = 1;
/// `GlyphInstance::kind`: a point (a = b), drawn as a disc with a rim.
pub const KIND_POINT: u32 = 0;
/// `GlyphInstance::kind`: a line from a to b.
pub const KIND_LINE: u32 = 1;

/// The glyph pass's uniforms: `GlyphUniforms` in shaders/glyph.wgsl ([`INTERFACE`]).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct GlyphUniforms {
    pub clip_from_ref: [[f32; 4]; 4],
    pub ref_from_clip: [[f32; 4]; 4],
    /// Slices: the plane n·x = `plane_offset_mm` (unit n, ref mm).
    pub plane_normal_ref: [f32; 3],
    pub plane_offset_mm: f32,
    pub viewport_px: [f32; 2],
    /// [`MODE_VIEW`] or [`MODE_SLICE`].
    pub mode: u32,
    pub occluded_alpha: f32,
    pub depth_tolerance_mm: f32,
    pub slab_half_mm: f32,
    pub outline_px: f32,
    _pad0: f32,
}
const _: () = assert!(std::mem::size_of::<GlyphUniforms>() == 176);

/// One glyph, a per-instance vertex: `GlyphInstance` in shaders/glyph.wgsl, whose locations are the fields in order
/// ([`GlyphRenderer::new`]'s vertex attributes).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct GlyphInstance {
    pub a_ref: [f32; 3],
    pub radius_px: f32,
    /// The other end of a line; equal to `a_ref` for a point.
    pub b_ref: [f32; 3],
    /// [`KIND_POINT`] or [`KIND_LINE`].
    pub kind: u32,
    /// Straight (not premultiplied) RGBA.
    pub colour: [f32; 4],
}
const _: () = assert!(std::mem::size_of::<GlyphInstance>() == 48);

impl GlyphInstance {
    #[must_use]
    pub fn point(p_ref: Vec3, radius_px: f32, colour: [f32; 4]) -> Self {
        Self { a_ref: p_ref.to_array(), radius_px, b_ref: p_ref.to_array(), kind: KIND_POINT, colour }
    }

    #[must_use]
    pub fn line(a_ref: Vec3, b_ref: Vec3, width_px: f32, colour: [f32; 4]) -> Self {
        Self { a_ref: a_ref.to_array(), radius_px: 0.5 * width_px, b_ref: b_ref.to_array(), kind: KIND_LINE, colour }
    }
}

/// How glyphs meet the volume and the slice.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GlyphSettings {
    /// Opacity factor of glyph fragments behind the first hit (0 hides them).
    pub occluded_alpha: f32,
    /// A fragment counts as behind only when farther than the hit by more than this (mm): a landmark picked on a
    /// surface lies on it, within the ray caster's step.
    pub depth_tolerance_mm: f32,
    /// Slices: glyphs farther from the plane than this (mm) are not drawn.
    pub slab_half_mm: f32,
    /// Width of a point's dark rim (px).
    pub outline_px: f32,
}

impl Default for GlyphSettings {
    fn default() -> Self {
        Self { occluded_alpha: 0.25, depth_tolerance_mm: 1.0, slab_half_mm: 3.0, outline_px: 1.5 }
    }
}

impl GlyphUniforms {
    /// For the 3-D view of `camera` at `size_px`, the same framing as [`crate::RaycastUniforms::new`].
    #[must_use]
    pub fn for_view(camera: &OrbitCamera, size_px: (u32, u32), settings: &GlyphSettings) -> Self {
        let (w, h) = (size_px.0.max(1), size_px.1.max(1));
        let aspect = w as f32 / h as f32;
        Self::new(
            camera.clip_from_ref(aspect),
            camera.ref_from_clip(aspect),
            [0.0; 3],
            0.0,
            (w, h),
            MODE_VIEW,
            settings,
        )
    }

    /// For a slice through `plane` (its size is the viewport). Errors when the plane is degenerate.
    pub fn for_slice(plane: &SlicePlane, settings: &GlyphSettings) -> Result<Self> {
        let n = plane
            .normal_ref()
            .map(DVec3::from_array)
            .ok_or_else(|| GpuError::InvalidInput("the slice plane's pixel axes are parallel".into()))?;
        let (w, h) = (plane.size.0.max(1), plane.size.1.max(1));
        // frag px (x, y, d) → ref: columns u, v, n and the origin (pixel centres at i + ½, as in the ray caster).
        let ref_from_frag = DMat4::from_cols(
            DVec3::from_array(plane.u_ref).extend(0.0),
            DVec3::from_array(plane.v_ref).extend(0.0),
            n.extend(0.0),
            DVec3::from_array(plane.origin_ref).extend(1.0),
        );
        if ref_from_frag.determinant().abs() < 1e-30 {
            return Err(GpuError::InvalidInput("the slice plane is degenerate".into()));
        }
        let ndc_from_frag = DMat4::from_cols_array_2d(&[
            [2.0 / f64::from(w), 0.0, 0.0, 0.0],
            [0.0, -2.0 / f64::from(h), 0.0, 0.0],
            [0.0, 0.0, 0.0, 0.0],
            [-1.0, 1.0, 0.5, 1.0],
        ]);
        let clip_from_ref = (ndc_from_frag * ref_from_frag.inverse()).as_mat4();
        let offset = n.dot(DVec3::from_array(plane.origin_ref));
        Ok(Self::new(
            clip_from_ref,
            Mat4::IDENTITY,
            n.as_vec3().to_array(),
            offset as f32,
            (w, h),
            MODE_SLICE,
            settings,
        ))
    }

    fn new(
        clip_from_ref: Mat4,
        ref_from_clip: Mat4,
        plane_normal_ref: [f32; 3],
        plane_offset_mm: f32,
        (w, h): (u32, u32),
        mode: u32,
        s: &GlyphSettings,
    ) -> Self {
        Self {
            clip_from_ref: clip_from_ref.to_cols_array_2d(),
            ref_from_clip: ref_from_clip.to_cols_array_2d(),
            plane_normal_ref,
            plane_offset_mm,
            viewport_px: [w as f32, h as f32],
            mode,
            occluded_alpha: s.occluded_alpha.clamp(0.0, 1.0),
            depth_tolerance_mm: s.depth_tolerance_mm.max(0.0),
            slab_half_mm: s.slab_half_mm.max(1e-3),
            outline_px: s.outline_px.max(0.0),
            _pad0: 0.0,
        }
    }
}

/// One landmark pair as glyphs see it: ref-space positions (either may be missing while a pair is being placed).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GlyphPair {
    /// Where the source (moving) point is drawn: d(pᵢ) in the deformed view, pᵢ without the warp (module docs).
    pub moving_ref: Option<Vec3>,
    /// The target (fixed) point qᵢ.
    pub fixed_ref: Option<Vec3>,
    pub selected: bool,
    /// An inactive pair (left out of the fit) is drawn faded.
    pub active: bool,
}

/// Colours and sizes of [`pair_glyphs`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GlyphStyle {
    pub moving_colour: [f32; 4],
    pub fixed_colour: [f32; 4],
    pub line_colour: [f32; 4],
    pub point_radius_px: f32,
    pub line_width_px: f32,
    /// Radius factor of the selected pair's points.
    pub selected_scale: f32,
    /// Opacity factor of inactive pairs.
    pub inactive_alpha: f32,
}

impl Default for GlyphStyle {
    /// Moving points orange, fixed points blue, lines white: distinct from the red/cyan fusion colours and from grey
    /// anatomy.
    fn default() -> Self {
        Self {
            moving_colour: [1.0, 0.55, 0.0, 1.0],
            fixed_colour: [0.15, 0.55, 1.0, 1.0],
            line_colour: [1.0, 1.0, 1.0, 0.85],
            point_radius_px: 5.0,
            line_width_px: 2.0,
            selected_scale: 1.5,
            inactive_alpha: 0.35,
        }
    }
}

/// The glyphs of `pairs`: all lines first, then the points, so points are drawn over lines.
#[must_use]
pub fn pair_glyphs(pairs: &[GlyphPair], style: &GlyphStyle) -> Vec<GlyphInstance> {
    let fade = |c: [f32; 4], pair: &GlyphPair| {
        let a = if pair.active { 1.0 } else { style.inactive_alpha };
        [c[0], c[1], c[2], c[3] * a]
    };
    let lines = pairs.iter().filter_map(|pair| match (pair.moving_ref, pair.fixed_ref) {
        (Some(m), Some(f)) => Some(GlyphInstance::line(m, f, style.line_width_px, fade(style.line_colour, pair))),
        _ => None,
    });
    let points = pairs.iter().flat_map(|pair| {
        let r = style.point_radius_px * if pair.selected { style.selected_scale } else { 1.0 };
        let m = pair.moving_ref.map(|p| GlyphInstance::point(p, r, fade(style.moving_colour, pair)));
        let f = pair.fixed_ref.map(|p| GlyphInstance::point(p, r, fade(style.fixed_colour, pair)));
        m.into_iter().chain(f)
    });
    lines.chain(points).collect()
}

/// The long-lived part of the glyph pass: pipeline, layout and the placeholder hit depth bound for slices.
#[derive(Debug)]
pub struct GlyphRenderer {
    pipeline: wgpu::RenderPipeline,
    layout: wgpu::BindGroupLayout,
    placeholder_hit_depth: wgpu::TextureView,
}

impl GlyphRenderer {
    pub fn new(ctx: &GpuContext) -> Result<Self> {
        let device = &ctx.device;
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("glyph"),
            entries: &[
                SLOT_UNIFORMS.layout_entry(
                    wgpu::ShaderStages::VERTEX_FRAGMENT,
                    wgpu::BindingType::Buffer {
                        ty: wgpu::BufferBindingType::Uniform,
                        has_dynamic_offset: false,
                        min_binding_size: wgpu::BufferSize::new(std::mem::size_of::<GlyphUniforms>() as u64),
                    },
                ),
                SLOT_HIT_DEPTH.layout_entry(
                    wgpu::ShaderStages::FRAGMENT,
                    wgpu::BindingType::Texture {
                        sample_type: wgpu::TextureSampleType::Uint,
                        view_dimension: wgpu::TextureViewDimension::D2,
                        multisampled: false,
                    },
                ),
            ],
        });
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("glyph"),
            bind_group_layouts: &[Some(&layout)],
            immediate_size: 0,
        });
        let module = SHADER.create_module(device);
        let attributes = wgpu::vertex_attr_array![
            0 => Float32x3, 1 => Float32, 2 => Float32x3, 3 => Uint32, 4 => Float32x4
        ];
        let premultiplied_over = wgpu::BlendComponent {
            src_factor: wgpu::BlendFactor::One,
            dst_factor: wgpu::BlendFactor::OneMinusSrcAlpha,
            operation: wgpu::BlendOperation::Add,
        };
        let pipeline = device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some("glyph"),
            layout: Some(&pipeline_layout),
            vertex: wgpu::VertexState {
                module: &module,
                entry_point: SHADER.entry_point(Stage::Vertex),
                compilation_options: wgpu::PipelineCompilationOptions::default(),
                buffers: &[Some(wgpu::VertexBufferLayout {
                    array_stride: std::mem::size_of::<GlyphInstance>() as u64,
                    step_mode: wgpu::VertexStepMode::Instance,
                    attributes: &attributes,
                })],
            },
            primitive: wgpu::PrimitiveState::default(),
            depth_stencil: None,
            multisample: wgpu::MultisampleState::default(),
            fragment: Some(wgpu::FragmentState {
                module: &module,
                entry_point: SHADER.entry_point(Stage::Fragment),
                compilation_options: wgpu::PipelineCompilationOptions::default(),
                targets: &[Some(wgpu::ColorTargetState {
                    format: RenderTarget::COLOUR_FORMAT,
                    blend: Some(wgpu::BlendState { color: premultiplied_over, alpha: premultiplied_over }),
                    write_mask: wgpu::ColorWrites::ALL,
                })],
            }),
            multiview_mask: None,
            cache: None,
        });
        let placeholder = device.create_texture(&wgpu::TextureDescriptor {
            label: Some("glyph placeholder hit depth"),
            size: wgpu::Extent3d { width: 1, height: 1, depth_or_array_layers: 1 },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: RenderTarget::HIT_DEPTH_FORMAT,
            usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
            view_formats: &[],
        });
        ctx.queue.write_texture(
            placeholder.as_image_copy(),
            bytemuck::bytes_of(&NO_HIT_DEPTH.to_bits()),
            wgpu::TexelCopyBufferLayout { offset: 0, bytes_per_row: Some(4), rows_per_image: Some(1) },
            wgpu::Extent3d { width: 1, height: 1, depth_or_array_layers: 1 },
        );
        let placeholder_hit_depth = placeholder.create_view(&wgpu::TextureViewDescriptor::default());
        ctx.check_errors()?;
        Ok(Self { pipeline, layout, placeholder_hit_depth })
    }

    /// Records the glyphs of `data` into `pass` (one [`RenderTarget::COLOUR_FORMAT`] colour attachment).
    pub fn draw(&self, pass: &mut wgpu::RenderPass<'_>, data: &GlyphDrawData) {
        if data.count == 0 {
            return;
        }
        pass.set_pipeline(&self.pipeline);
        pass.set_bind_group(0, &data.bind_group, &[]);
        pass.set_vertex_buffer(0, data.instances.slice(..));
        pass.draw(0..6, 0..data.count);
    }

    /// Draws `data` over what `target` holds (a frame or a slice just rendered into it) and submits.
    pub fn render(&self, ctx: &GpuContext, data: &GlyphDrawData, target: &RenderTarget) -> Result<()> {
        let mut encoder = ctx.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("glyph") });
        {
            let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("glyph"),
                color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                    view: &target.view,
                    depth_slice: None,
                    resolve_target: None,
                    ops: wgpu::Operations { load: wgpu::LoadOp::Load, store: wgpu::StoreOp::Store },
                })],
                depth_stencil_attachment: None,
                timestamp_writes: None,
                occlusion_query_set: None,
                multiview_mask: None,
            });
            self.draw(&mut pass, data);
        }
        ctx.queue.submit([encoder.finish()]);
        ctx.check_errors()
    }
}

/// One draw's glyphs: uniforms, the instance buffer and the bind group (with the hit depth of the frame they go
/// over).
#[derive(Debug)]
pub struct GlyphDrawData {
    pub uniforms: GlyphUniforms,
    uniform_buffer: wgpu::Buffer,
    instances: wgpu::Buffer,
    count: u32,
    bind_group: wgpu::BindGroup,
}

impl GlyphDrawData {
    /// `hit_depth`: the frame's [`RenderTarget::hit_depth_view`] in the 3-D view; `None` for slices.
    #[must_use]
    pub fn new(
        ctx: &GpuContext,
        renderer: &GlyphRenderer,
        uniforms: GlyphUniforms,
        glyphs: &[GlyphInstance],
        hit_depth: Option<&wgpu::TextureView>,
    ) -> Self {
        let uniform_buffer = ctx.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("glyph uniforms"),
            size: std::mem::size_of::<GlyphUniforms>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        ctx.queue.write_buffer(&uniform_buffer, 0, bytemuck::bytes_of(&uniforms));
        let bind_group = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("glyph"),
            layout: &renderer.layout,
            entries: &[
                SLOT_UNIFORMS.entry(uniform_buffer.as_entire_binding()),
                SLOT_HIT_DEPTH
                    .entry(wgpu::BindingResource::TextureView(hit_depth.unwrap_or(&renderer.placeholder_hit_depth))),
            ],
        });
        let instances = Self::instance_buffer(ctx, glyphs.len());
        let mut data = Self { uniforms, uniform_buffer, instances, count: 0, bind_group };
        data.update(ctx, uniforms, glyphs);
        data
    }

    /// New uniforms and glyphs (a drag, a camera move); the instance buffer grows only when it must.
    pub fn update(&mut self, ctx: &GpuContext, uniforms: GlyphUniforms, glyphs: &[GlyphInstance]) {
        self.uniforms = uniforms;
        ctx.queue.write_buffer(&self.uniform_buffer, 0, bytemuck::bytes_of(&uniforms));
        let bytes = std::mem::size_of_val(glyphs) as u64;
        if bytes > self.instances.size() {
            self.instances = Self::instance_buffer(ctx, glyphs.len().next_power_of_two());
        }
        if !glyphs.is_empty() {
            ctx.queue.write_buffer(&self.instances, 0, bytemuck::cast_slice(glyphs));
        }
        self.count = u32::try_from(glyphs.len()).unwrap_or(u32::MAX);
    }

    fn instance_buffer(ctx: &GpuContext, capacity: usize) -> wgpu::Buffer {
        ctx.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("glyph instances"),
            size: (capacity.max(1) * std::mem::size_of::<GlyphInstance>()) as u64,
            usage: wgpu::BufferUsages::VERTEX | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    #[allow(clippy::float_cmp, reason = "the style's values are copied or multiplied once, exactly")]
    fn pair_glyphs_draw_lines_under_points_and_skip_missing_ends() {
        let pairs = [
            GlyphPair { moving_ref: Some(Vec3::X), fixed_ref: Some(Vec3::Y), selected: false, active: true },
            GlyphPair { moving_ref: Some(Vec3::Z), fixed_ref: None, selected: true, active: false },
        ];
        let style = GlyphStyle::default();
        let g = pair_glyphs(&pairs, &style);
        let kinds: Vec<u32> = g.iter().map(|i| i.kind).collect();
        assert_eq!(kinds, [KIND_LINE, KIND_POINT, KIND_POINT, KIND_POINT]);
        assert_eq!(g[3].radius_px, style.point_radius_px * style.selected_scale);
        assert_eq!(g[3].colour[3], style.inactive_alpha);
        assert_eq!(g[1].colour, style.moving_colour);
        assert_eq!(g[2].colour, style.fixed_colour);
    }

    #[test]
    fn slice_uniforms_map_pixel_centres_to_ndc() {
        let plane = SlicePlane {
            origin_ref: [10.0, -20.0, 5.0],
            u_ref: [0.5, 0.0, 0.0],
            v_ref: [0.0, 0.0, -0.5],
            size: (40, 30),
        };
        let u = GlyphUniforms::for_slice(&plane, &GlyphSettings::default()).expect("plane");
        let clip_from_ref = Mat4::from_cols_array_2d(&u.clip_from_ref);
        let p = DVec3::from_array(plane.ref_from_pixel(7.0, 11.0)).as_vec3();
        let ndc = clip_from_ref.project_point3(p);
        let px = ((ndc.x + 1.0) * 0.5 * 40.0, (1.0 - ndc.y) * 0.5 * 30.0);
        assert!((px.0 - 7.5).abs() < 1e-4 && (px.1 - 11.5).abs() < 1e-4, "{px:?}");
        // The normal is u × v / |u × v| and the plane passes through the origin.
        let n = Vec3::from_array(u.plane_normal_ref);
        assert!((n - Vec3::new(0.0, 1.0, 0.0)).length() < 1e-6, "{n}");
        assert!((n.dot(p) - u.plane_offset_mm).abs() < 1e-4);
        let degenerate = SlicePlane { v_ref: [1.0, 0.0, 0.0], ..plane };
        assert!(GlyphUniforms::for_slice(&degenerate, &GlyphSettings::default()).is_err());
    }
}
