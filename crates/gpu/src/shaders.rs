//! The shader registry: every WGSL file of the crate, with its entry points and the uniform structs that have a
//! Rust twin. The runtime creates modules from [`ShaderSource`]s here, and `tests/shaders.rs` validates each one with
//! naga (no device) and checks the Rust struct sizes against naga's layout of the WGSL struct of the same name.

use crate::control_eval::{BSplineUniforms, ControlEvalUniforms, LatticeUniforms};
use crate::export::ExportUniforms;
use crate::glyph::GlyphUniforms;
use crate::pick::{PickHit, PickRay, PickUniforms};
use crate::prefilter::PrefilterUniforms;
use crate::raycast::{RaycastUniforms, VolumeUniforms};

/// A pipeline stage, as the registry records entry points.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Stage {
    Vertex,
    Fragment,
    Compute,
}

/// One WGSL file.
#[derive(Clone, Copy, Debug)]
pub struct ShaderSource {
    /// Label, also used in error messages.
    pub name: &'static str,
    /// Path relative to the workspace root.
    pub path: &'static str,
    pub source: &'static str,
    pub entry_points: &'static [(&'static str, Stage)],
    /// The WGSL structs that have a `#[repr(C)]` Rust twin.
    pub uniform_structs: &'static [StructLayout],
}

/// A Rust struct's layout, to compare with naga's layout of the WGSL struct of the same name.
#[derive(Clone, Copy, Debug)]
pub struct StructLayout {
    pub name: &'static str,
    pub size: usize,
    /// `(field name, byte offset)`, in declaration order; padding fields (`_pad*`) are left out.
    pub fields: &'static [(&'static str, usize)],
}

/// `layout!(Type { field, field, … })`: the [`StructLayout`] of a Rust struct from `size_of` and `offset_of!`.
macro_rules! layout {
    ($ty:ident { $($field:ident),* $(,)? }) => {
        StructLayout {
            name: stringify!($ty),
            size: std::mem::size_of::<$ty>(),
            fields: &[$((stringify!($field), std::mem::offset_of!($ty, $field))),*],
        }
    };
}

impl ShaderSource {
    #[must_use]
    pub fn create_module(&self, device: &wgpu::Device) -> wgpu::ShaderModule {
        device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some(self.name),
            source: wgpu::ShaderSource::Wgsl(self.source.into()),
        })
    }

    /// The name of the entry point for `stage` (the first one listed).
    #[must_use]
    pub fn entry_point(&self, stage: Stage) -> Option<&'static str> {
        self.entry_points.iter().find(|(_, s)| *s == stage).map(|(n, _)| *n)
    }
}

/// The ray caster: `vs_fullscreen` + `fs_raycast` (see [`crate::raycast`]), `fs_slice` (see [`crate::slice`]) and
/// `cs_pick` (see [`crate::pick`]).
pub const RAYCAST: ShaderSource = ShaderSource {
    name: "raycast",
    path: "shaders/raycast.wgsl",
    source: include_str!("../../../shaders/raycast.wgsl"),
    entry_points: &[
        ("vs_fullscreen", Stage::Vertex),
        ("fs_raycast", Stage::Fragment),
        ("fs_slice", Stage::Fragment),
        ("cs_pick", Stage::Compute),
    ],
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
            iso_value
        }),
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
            ref_from_frag_px
        }),
        layout!(PickUniforms { probe, target_volume, threshold, ray_count, bisection_steps }),
        layout!(PickRay { origin_ref, dir_ref }),
        layout!(PickHit { x_ref, t_mm, p_lps, value, hit, target_volume }),
    ],
};

/// The gradient prefilter: `cs_gaussian_from_volume` (x) and `cs_gaussian_from_layers` (y, z), one axis of a separable Gaussian (see [`crate::prefilter`]).
pub const PREFILTER: ShaderSource = ShaderSource {
    name: "prefilter",
    path: "shaders/prefilter.wgsl",
    source: include_str!("../../../shaders/prefilter.wgsl"),
    entry_points: &[("cs_gaussian_from_volume", Stage::Compute), ("cs_gaussian_from_layers", Stage::Compute)],
    uniform_structs: &[layout!(PrefilterUniforms { axis, radius_vox, sigma_vox, dst_dims })],
};

/// Landmark glyphs: `vs_glyph` + `fs_glyph`, screen-space capsules over a frame or a slice (see [`crate::glyph`]).
pub const GLYPH: ShaderSource = ShaderSource {
    name: "glyph",
    path: "shaders/glyph.wgsl",
    source: include_str!("../../../shaders/glyph.wgsl"),
    entry_points: &[("vs_glyph", Stage::Vertex), ("fs_glyph", Stage::Fragment)],
    uniform_structs: &[layout!(GlyphUniforms {
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
    })],
};

/// GPU control-texture evaluation: `cs_tps` and `cs_bspline`, a pull-back's displacement at every texel centre into a
/// staging buffer, with its bounds reduced (see [`crate::control_eval`]).
pub const CONTROL_EVAL: ShaderSource = ShaderSource {
    name: "control_eval",
    path: "shaders/control_eval.wgsl",
    source: include_str!("../../../shaders/control_eval.wgsl"),
    entry_points: &[("cs_tps", Stage::Compute), ("cs_bspline", Stage::Compute)],
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
};

/// The export of the warped volume: `cs_export`, one z-slab of the target per dispatch (see [`crate::export`]).
pub const EXPORT: ShaderSource = ShaderSource {
    name: "export",
    path: "shaders/export.wgsl",
    source: include_str!("../../../shaders/export.wgsl"),
    entry_points: &[("cs_export", Stage::Compute)],
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
};

/// Every shader of the crate.
pub const ALL: &[ShaderSource] = &[RAYCAST, PREFILTER, GLYPH, CONTROL_EVAL, EXPORT];
