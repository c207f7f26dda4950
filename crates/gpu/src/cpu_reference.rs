//! The ray caster's math in f32 on the CPU: an oracle for the GPU pass (`shaders/raycast.wgsl`), with the same
//! texel-centre and clamp-to-edge conventions, the same transfer-function sampling (linear between the 256 entries),
//! the same opacity correction, blend modes, jitter hash and front-to-back compositing. Single-threaded; meant for
//! small images (64² in the tests).
//!
//! It consumes exactly what the GPU consumes: the [`RaycastUniforms`] of the frame, the [`PreparedVolume`]s and
//! [`PreparedControl`]s whose texels were uploaded, the [`PrefilteredTexels`] the gradients come from, and the
//! [`TransferFunction`] rows. Shading (DVR and iso-surface, gradients through the warp) follows the shader's
//! formulas exactly: see `shaders/raycast.wgsl` and [`crate::settings::Shading`]. Slices ([`crate::slice`]):
//! [`slice_pixel`], [`render_slice`].

use glam::{Mat4, Vec3, Vec4};

use crate::control::PreparedControl;
use crate::glyph::{
    GlyphInstance, GlyphUniforms, KIND_POINT, MODE_SLICE as GLYPH_MODE_SLICE, MODE_VIEW as GLYPH_MODE_VIEW,
};
use crate::pick::{PickHit, PickRay, PickRequest, PickTarget, Probe};
use crate::prefilter::PrefilteredTexels;
use crate::procedural::PROCEDURAL_NONE;
use crate::raycast::{
    EARLY_EXIT_ALPHA, RAYCAST_JITTER, RAYCAST_PREINTEGRATED, RaycastUniforms, VOLUME_HAS_PREFILTER, VOLUME_HAS_WARP,
    VOLUME_VISIBLE, VolumeUniforms,
};
use crate::sampling::{FilterPrecision, trilinear_with};
use crate::settings::ShadingMode;
use crate::target::{HIT_OPACITY, NO_HIT_DEPTH};
use crate::transfer::{PreIntegrationTable, TransferFunction};
use crate::view_deformation::{VIEW_EMPTY, VIEW_NONE};
use crate::volume::PreparedVolume;

/// One volume on the CPU side: its texels, optional control texture and optional prefiltered copy, and the
/// precision of the hardware filter the GPU reads them with.
#[derive(Clone, Copy, Debug)]
pub struct CpuLayer<'a> {
    pub volume: &'a PreparedVolume,
    pub control: Option<&'a PreparedControl>,
    /// Used where the uniforms say `VOLUME_HAS_PREFILTER`.
    pub prefiltered: Option<&'a PrefilteredTexels>,
    /// The lookups the shader leaves to the hardware filter, as the device filters them: the control texture's,
    /// and the volume's unless it is filtered by hand (`VolumeInfo::manual_filter`). [`FilterPrecision::EXACT`] is
    /// the exact reference; picks are always exact, as the GPU's are ([`crate::pick`]).
    pub filtering: FilterPrecision,
}

impl<'a> CpuLayer<'a> {
    /// A layer read with exact weights.
    #[must_use]
    pub fn new(
        volume: &'a PreparedVolume,
        control: Option<&'a PreparedControl>,
        prefiltered: Option<&'a PrefilteredTexels>,
    ) -> Self {
        Self { volume, control, prefiltered, filtering: FilterPrecision::EXACT }
    }

    /// The same layer read with hardware weights of `filtering`.
    #[must_use]
    pub fn with_filtering(self, filtering: FilterPrecision) -> Self {
        Self { filtering, ..self }
    }

    /// The volume's normalised texel at `p_tex` as the GPU filters it: exact when the shader filters it by hand.
    fn volume_texel(&self, p_tex: Vec3) -> f32 {
        let vol = self.volume;
        let filtering = if vol.info.manual_filter { FilterPrecision::EXACT } else { self.filtering };
        let texel = |i| Vec4::splat(vol.texels.normalised(i));
        filtering.result(vol.texels.format(), trilinear_with(filtering.weights, vol.info.dims, p_tex, texel).x)
    }
}

/// Below this squared gradient length the normal is undefined and |n·l| = 1 (the shader's `MIN_GRADIENT_SQ`).
const MIN_GRADIENT_SQ: f32 = 1e-12;

/// The shader's `pcg_hash`.
#[must_use]
pub fn pcg_hash(v: u32) -> u32 {
    let state = v.wrapping_mul(747_796_405).wrapping_add(2_891_336_453);
    let word = ((state >> ((state >> 28) + 4)) ^ state).wrapping_mul(277_803_737);
    (word >> 22) ^ word
}

/// Samples row `row` of `tfs` (the shader's `sample_tf`).
fn tf_sample(tfs: &[TransferFunction], row: u32, t: f32) -> Vec4 {
    tfs.get(row as usize).map_or(Vec4::ZERO, |tf| Vec4::from_array(tf.sample(t)))
}

/// The shader's `pullback_lps`: u(w(x_ref)) in the volume's LPS space (the point a landmark records).
#[must_use]
pub fn pullback_lps(layer: &CpuLayer<'_>, v: &VolumeUniforms, x_ref: Vec3) -> Vec3 {
    let y = if v.view.kind == VIEW_NONE { x_ref } else { v.view.pullback(x_ref) };
    if v.flags & VOLUME_HAS_WARP != 0
        && let Some(ctrl) = layer.control
    {
        let c_tex = Mat4::from_cols_array_2d(&v.ctrl_tex_from_ref).transform_point3(y);
        let d = trilinear_with(layer.filtering.weights, ctrl.info.dims, c_tex, |i| Vec4::from_array(ctrl.texels[i]));
        return y + d.truncate();
    }
    y
}

/// The shader's `procedural_lps`: p(y), the volume's LPS point whose data its LPS point y shows.
#[must_use]
pub fn procedural_lps(v: &VolumeUniforms, y_lps: Vec3) -> Vec3 {
    if v.procedural.kind == PROCEDURAL_NONE { y_lps } else { y_lps + v.procedural.displacement(y_lps) }
}

/// The shader's `data_tex`: tex(p(y)) of the volume's LPS point y, through its procedural deformation.
#[must_use]
pub fn data_tex(v: &VolumeUniforms, y_lps: Vec3) -> Vec3 {
    Mat4::from_cols_array_2d(&v.tex_from_lps).transform_point3(procedural_lps(v, y_lps))
}

/// The shader's `data_lps`: Φ(x_ref) = p(u(w(x_ref))), the volume's LPS point whose data ref point x_ref shows.
#[must_use]
pub fn data_lps(layer: &CpuLayer<'_>, v: &VolumeUniforms, x_ref: Vec3) -> Vec3 {
    procedural_lps(v, pullback_lps(layer, v, x_ref))
}

/// The shader's `warp_to_tex`: tex(Φ(x_ref)).
#[must_use]
pub fn warp_to_tex(layer: &CpuLayer<'_>, v: &VolumeUniforms, x_ref: Vec3) -> Vec3 {
    Mat4::from_cols_array_2d(&v.tex_from_lps).transform_point3(data_lps(layer, v, x_ref))
}

/// The shader's `undeformed`: Φ is the identity (no warp, no view or procedural deformation).
fn undeformed(v: &VolumeUniforms) -> bool {
    v.flags & VOLUME_HAS_WARP == 0 && v.view.kind == VIEW_NONE && v.procedural.kind == PROCEDURAL_NONE
}

fn outside_tex(p_tex: Vec3) -> bool {
    p_tex.cmplt(Vec3::ZERO).any() || p_tex.cmpgt(Vec3::ONE).any()
}

/// The shader's `volume_value`.
fn volume_value(layer: &CpuLayer<'_>, v: &VolumeUniforms, p_tex: Vec3) -> f32 {
    v.value_offset + v.value_scale * layer.volume_texel(p_tex)
}

/// The shader's `warped_gradient_at`: the gradient of the deformed volume at `x_ref`, ∇(v∘Φ)(x_ref), in
/// normalised texel units per mm, `y_lps` being Φ(x_ref). With a prefiltered copy, J_Φᵀ ∇v(Φ(x)) from the copy's
/// gradient texels filtered as the hardware does ([`CpuLayer::filtering`]); without one, central differences of the
/// volume through the warp (see `shaders/raycast.wgsl`).
#[must_use]
pub fn warped_gradient_at(
    layer: &CpuLayer<'_>,
    u: &RaycastUniforms,
    v: &VolumeUniforms,
    x_ref: Vec3,
    y_lps: Vec3,
) -> Vec3 {
    let h = u.gradient_step_mm;
    let prefiltered = layer.prefiltered.filter(|_| v.flags & VOLUME_HAS_PREFILTER != 0);
    let Some(pf) = prefiltered else {
        let mut g = Vec3::ZERO;
        for i in 0..3 {
            let mut e = Vec3::ZERO;
            e[i] = h;
            let plus = layer.volume_texel(warp_to_tex(layer, v, x_ref + e));
            let minus = layer.volume_texel(warp_to_tex(layer, v, x_ref - e));
            g[i] = (plus - minus) / (2.0 * h);
        }
        return g;
    };
    let m = Mat4::from_cols_array_2d(&v.tex_from_lps);
    let p_tex = m.transform_point3(y_lps);
    let g_tex =
        trilinear_with(layer.filtering.weights, pf.dims, p_tex, |i| Vec4::from_array(pf.gradients[i])).truncate();
    let g_lps =
        Vec3::new(m.x_axis.truncate().dot(g_tex), m.y_axis.truncate().dot(g_tex), m.z_axis.truncate().dot(g_tex));
    if undeformed(v) {
        return g_lps;
    }
    let mut g = Vec3::ZERO;
    for i in 0..3 {
        let mut e = Vec3::ZERO;
        e[i] = h;
        let (plus_w, minus_w) = (pullback_lps(layer, v, x_ref + e), pullback_lps(layer, v, x_ref - e));
        let (mut plus, mut minus, mut span) = (y_lps, y_lps, 0.0);
        if plus_w.x != VIEW_EMPTY {
            plus = procedural_lps(v, plus_w);
            span += h;
        }
        if minus_w.x != VIEW_EMPTY {
            minus = procedural_lps(v, minus_w);
            span += h;
        }
        if span > 0.0 {
            g[i] = (plus - minus).dot(g_lps) / span;
        }
    }
    g
}

/// The shader's `warped_gradient`: [`warped_gradient_at`] with the data point looked up here.
#[must_use]
pub fn warped_gradient(layer: &CpuLayer<'_>, u: &RaycastUniforms, v: &VolumeUniforms, x_ref: Vec3) -> Vec3 {
    warped_gradient_at(layer, u, v, x_ref, data_lps(layer, v, x_ref))
}

/// The shader's `shade`: headlight lighting of straight colour `rgb` with gradient `g`, `light` towards the eye.
#[must_use]
pub fn shade(u: &RaycastUniforms, rgb: Vec3, g: Vec3, light: Vec3) -> Vec3 {
    let len_sq = g.dot(g);
    let n_dot_l = if len_sq > MIN_GRADIENT_SQ { g.dot(light).abs() / len_sq.sqrt() } else { 1.0 }.min(1.0);
    let spec = if u.specular > 0.0 { u.specular * (u.shininess * n_dot_l.max(1e-7).log2()).exp2() } else { 0.0 };
    (rgb * (u.ambient + u.diffuse * n_dot_l) + Vec3::splat(spec)).clamp(Vec3::ZERO, Vec3::ONE)
}

/// The shader's `classify`: premultiplied, opacity-corrected RGBA of one volume at `x_ref`, lit in DVR mode.
#[must_use]
pub fn classify(
    layer: &CpuLayer<'_>,
    u: &RaycastUniforms,
    v: &VolumeUniforms,
    tfs: &[TransferFunction],
    x_ref: Vec3,
    light: Vec3,
) -> Vec4 {
    let y_lps = data_lps(layer, v, x_ref);
    let p_tex = Mat4::from_cols_array_2d(&v.tex_from_lps).transform_point3(y_lps);
    if outside_tex(p_tex) {
        return Vec4::ZERO;
    }
    let value = volume_value(layer, v, p_tex);
    let t = ((value - v.window_low) / v.window_width).clamp(0.0, 1.0);
    let rgba = tf_sample(tfs, v.tf_row, t);
    let alpha = (rgba.w * v.opacity_scale).clamp(0.0, 1.0);
    let step_ratio = u.step_mm / u.ref_step_mm;
    let alpha_corrected = 1.0 - (step_ratio * (1.0 - alpha).max(1e-7).log2()).exp2();
    let mut rgb = rgba.truncate();
    if u.shading_mode == ShadingMode::Dvr.code() && alpha_corrected > 0.0 {
        rgb = shade(u, rgb, warped_gradient_at(layer, u, v, x_ref, y_lps), light);
    }
    (rgb * alpha_corrected).extend(alpha_corrected)
}

/// The (fixed, moving) pre-integration tables the GPU binds for frame `u` (each layer's TF row, opacity scale and
/// the frame's step), or `None` when the frame does not pre-integrate. Building one takes tens of ms (optimised).
#[must_use]
pub fn preintegration_tables(u: &RaycastUniforms, tfs: &[TransferFunction]) -> Option<[PreIntegrationTable; 2]> {
    if u.flags & RAYCAST_PREINTEGRATED == 0 {
        return None;
    }
    let step_ratio = u.step_mm / u.ref_step_mm;
    let transparent = TransferFunction { name: String::new(), entries: vec![[0; 4]; crate::transfer::TF_ENTRIES] };
    Some([&u.fixed, &u.moving].map(|v| {
        let tf = tfs.get(v.tf_row as usize).unwrap_or(&transparent);
        PreIntegrationTable::build(tf, v.opacity_scale, step_ratio)
    }))
}

/// The shader's `tf_coord_at`: the TF coordinate at `x_ref`, or −1 outside the volume's texture box.
fn tf_coord_at(layer: &CpuLayer<'_>, v: &VolumeUniforms, x_ref: Vec3) -> f32 {
    let p_tex = warp_to_tex(layer, v, x_ref);
    if outside_tex(p_tex) {
        return -1.0;
    }
    ((volume_value(layer, v, p_tex) - v.window_low) / v.window_width).clamp(0.0, 1.0)
}

/// The shader's `classify_segment`: one volume's pre-integrated segment from `t_front` to `t_back`, lit in DVR mode
/// at `x_shade`.
#[allow(clippy::too_many_arguments, reason = "the shader function's parameters")]
fn classify_segment(
    layer: &CpuLayer<'_>,
    u: &RaycastUniforms,
    v: &VolumeUniforms,
    table: &PreIntegrationTable,
    (t_front, t_back): (f32, f32),
    x_shade: Vec3,
    light: Vec3,
) -> Vec4 {
    if t_front < 0.0 || t_back < 0.0 {
        return Vec4::ZERO;
    }
    let c = Vec4::from_array(table.sample(t_front, t_back));
    if u.shading_mode == ShadingMode::Dvr.code() && c.w > 0.0 {
        let rgb = shade(u, c.truncate() / c.w, warped_gradient(layer, u, v, x_shade), light);
        return (rgb * c.w).extend(c.w);
    }
    c
}

/// The shader's `iso_value_at`.
fn iso_value_at(layer: &CpuLayer<'_>, v: &VolumeUniforms, x_ref: Vec3) -> f32 {
    let p_tex = warp_to_tex(layer, v, x_ref);
    if outside_tex(p_tex) { -3.4e38 } else { volume_value(layer, v, p_tex) }
}

/// The shader's `iso_hit`: the ray parameter of the first point with value ≥ `iso_value`, or `None`.
fn iso_hit(
    layer: &CpuLayer<'_>,
    u: &RaycastUniforms,
    v: &VolumeUniforms,
    ray: (Vec3, Vec3),
    span: (f32, f32),
    jitter: f32,
) -> Option<f32> {
    let (origin, dir) = ray;
    let (t_enter, t_far) = span;
    let mut t_prev: Option<f32> = None;
    for k in 0..u.max_steps {
        let t = t_enter + (k as f32 + jitter) * u.step_mm;
        if t >= t_far {
            break;
        }
        if iso_value_at(layer, v, origin + t * dir) >= v.iso_value {
            let Some(prev) = t_prev else { return Some(t) };
            let (mut lo, mut hi) = (prev, t);
            for _ in 0..u.bisection_steps {
                let mid = 0.5 * (lo + hi);
                if iso_value_at(layer, v, origin + mid * dir) >= v.iso_value {
                    hi = mid;
                } else {
                    lo = mid;
                }
            }
            return Some(0.5 * (lo + hi));
        }
        t_prev = Some(t);
    }
    None
}

/// The shader's `iso_colour`.
fn iso_colour(
    layer: &CpuLayer<'_>,
    u: &RaycastUniforms,
    v: &VolumeUniforms,
    tfs: &[TransferFunction],
    x_ref: Vec3,
    light: Vec3,
) -> Vec4 {
    let value = volume_value(layer, v, warp_to_tex(layer, v, x_ref));
    let t = ((value - v.window_low) / v.window_width).clamp(0.0, 1.0);
    shade(u, tf_sample(tfs, v.tf_row, t).truncate(), warped_gradient(layer, u, v, x_ref), light).extend(1.0)
}

fn luminance(c: Vec3) -> f32 {
    c.dot(Vec3::new(0.2126, 0.7152, 0.0722))
}

/// The shader's `blend` (premultiplied in and out).
#[must_use]
pub fn blend(u: &RaycastUniforms, f: Vec4, m: Vec4, x_ref: Vec3) -> Vec4 {
    match u.blend_mode {
        1 => (f + m).min(Vec4::ONE),
        2 => (f.truncate() - m.truncate()).abs().extend(f.w.max(m.w)),
        3 => {
            let cell = (x_ref / u.checker_cell_mm).floor();
            let s = cell.x as i32 + cell.y as i32 + cell.z as i32;
            if s & 1 == 0 { f } else { m }
        }
        4 => {
            let (lf, lm) = (luminance(f.truncate()), luminance(m.truncate()));
            Vec4::new(lf, lm, lm, 1.0 - (1.0 - f.w) * (1.0 - m.w))
        }
        5 => f,
        6 => m,
        _ => f.lerp(m, u.blend_weight),
    }
}

/// The span [t_enter, t_far] of the ray `origin + t·dir` inside the frame's proxy box (slab test, t ≥ 0), or `None`
/// when it misses, including a NaN t_far (a ray parallel to a face, outside its slab), as the shaders decide.
fn proxy_span(u: &RaycastUniforms, origin: Vec3, dir: Vec3) -> Option<(f32, f32)> {
    let inv_dir = dir.recip();
    let t0 = (Vec3::from_array(u.box_min_ref) - origin) * inv_dir;
    let t1 = (Vec3::from_array(u.box_max_ref) - origin) * inv_dir;
    let t_far = t0.max(t1).min_element();
    let t_enter = t0.min(t1).max_element().max(0.0);
    (t_far > t_enter).then_some((t_enter, t_far))
}

/// Premultiplied RGBA (not yet quantised) of the pixel whose centre is at `pixel_centre` (framebuffer coordinates,
/// y down, (x + ½, y + ½)).
#[must_use]
pub fn shade_pixel(
    u: &RaycastUniforms,
    fixed: &CpuLayer<'_>,
    moving: &CpuLayer<'_>,
    tfs: &[TransferFunction],
    pixel_centre: [f32; 2],
) -> Vec4 {
    shade_pixel_with_hit(u, fixed, moving, tfs, pixel_centre).0
}

/// The NDC depth of the point at distance `t` along a pixel's ray (the shader's `ndc_depth`).
fn ndc_depth(near_h: Vec4, far_h: Vec4, origin: Vec3, dir: Vec3, t: f32) -> f32 {
    let d = far_h - near_h;
    let k = (d.truncate() - origin * d.w).dot(dir);
    t * near_h.w / (k - t * d.w)
}

/// [`shade_pixel`] and the pixel's first-hit NDC depth ([`crate::RenderTarget::hit_depth`]: where the accumulated
/// opacity reaches [`HIT_OPACITY`], or the nearer iso hit; [`NO_HIT_DEPTH`] without a hit). A pre-integrating
/// frame builds its tables on each call: for many pixels use [`shade_pixel_with_tables`].
#[must_use]
pub fn shade_pixel_with_hit(
    u: &RaycastUniforms,
    fixed: &CpuLayer<'_>,
    moving: &CpuLayer<'_>,
    tfs: &[TransferFunction],
    pixel_centre: [f32; 2],
) -> (Vec4, f32) {
    shade_pixel_with_tables(u, fixed, moving, tfs, preintegration_tables(u, tfs).as_ref(), pixel_centre)
}

/// [`shade_pixel_with_hit`] with the frame's pre-integration tables built once by the caller
/// ([`preintegration_tables`]; `None` for a frame that does not pre-integrate).
#[must_use]
pub fn shade_pixel_with_tables(
    u: &RaycastUniforms,
    fixed: &CpuLayer<'_>,
    moving: &CpuLayer<'_>,
    tfs: &[TransferFunction],
    tables: Option<&[PreIntegrationTable; 2]>,
    pixel_centre: [f32; 2],
) -> (Vec4, f32) {
    let ref_from_clip = Mat4::from_cols_array_2d(&u.ref_from_clip);
    let ndc = [pixel_centre[0] / u.viewport_px[0] * 2.0 - 1.0, 1.0 - pixel_centre[1] / u.viewport_px[1] * 2.0];
    let near_h = ref_from_clip * Vec4::new(ndc[0], ndc[1], 0.0, 1.0);
    let far_h = ref_from_clip * Vec4::new(ndc[0], ndc[1], 1.0, 1.0);
    let origin = near_h.truncate() / near_h.w;
    let dir = (far_h.truncate() / far_h.w - origin).normalize();
    let Some((t_enter, t_far)) = proxy_span(u, origin, dir) else { return (Vec4::ZERO, NO_HIT_DEPTH) };
    let jitter = if u.flags & RAYCAST_JITTER != 0 {
        let (px, py) = (pixel_centre[0] as u32, pixel_centre[1] as u32);
        let h = pcg_hash(px.wrapping_add(pcg_hash(py.wrapping_add(pcg_hash(u.jitter_seed)))));
        (h >> 8) as f32 / 16_777_216.0
    } else {
        0.0
    };
    let use_fixed = u.fixed.flags & VOLUME_VISIBLE != 0 && u.blend_mode != 6;
    let use_moving = u.moving.flags & VOLUME_VISIBLE != 0 && u.blend_mode != 5;
    let light = -dir;
    if u.shading_mode == ShadingMode::Iso.code() {
        let span = (t_enter, t_far);
        let t_f = if use_fixed { iso_hit(fixed, u, &u.fixed, (origin, dir), span, jitter) } else { None };
        let t_m = if use_moving { iso_hit(moving, u, &u.moving, (origin, dir), span, jitter) } else { None };
        let f = t_f.map_or(Vec4::ZERO, |t| iso_colour(fixed, u, &u.fixed, tfs, origin + t * dir, light));
        let m = t_m.map_or(Vec4::ZERO, |t| iso_colour(moving, u, &u.moving, tfs, origin + t * dir, light));
        // The checkerboard picks its cell at the nearer hit.
        let t_near_hit = match (t_f, t_m) {
            (None, None) => return (Vec4::ZERO, NO_HIT_DEPTH),
            (Some(a), Some(b)) => a.min(b),
            (Some(a), None) | (None, Some(a)) => a,
        };
        return (blend(u, f, m, origin + t_near_hit * dir), ndc_depth(near_h, far_h, origin, dir, t_near_hit));
    }
    let mut acc = Vec4::ZERO;
    let mut hit_depth = NO_HIT_DEPTH;
    if u.flags & RAYCAST_PREINTEGRATED != 0
        && let Some([fixed_table, moving_table]) = tables
    {
        // The shader's `march_preintegrated` (without empty-space skipping, which does not change the image).
        let (mut front_f, mut front_m) = (-1.0f32, -1.0f32);
        for k in 0..u.max_steps {
            let t = t_enter + (k as f32 + jitter) * u.step_mm;
            if t >= t_far {
                break;
            }
            let x = origin + t * dir;
            let back_f = if use_fixed { tf_coord_at(fixed, &u.fixed, x) } else { -1.0 };
            let back_m = if use_moving { tf_coord_at(moving, &u.moving, x) } else { -1.0 };
            if k > 0 {
                let x_mid = x - (0.5 * u.step_mm) * dir;
                let f = if use_fixed {
                    classify_segment(fixed, u, &u.fixed, fixed_table, (front_f, back_f), x_mid, light)
                } else {
                    Vec4::ZERO
                };
                let m = if use_moving {
                    classify_segment(moving, u, &u.moving, moving_table, (front_m, back_m), x_mid, light)
                } else {
                    Vec4::ZERO
                };
                acc += (1.0 - acc.w) * blend(u, f, m, x_mid);
                if hit_depth == NO_HIT_DEPTH && acc.w >= HIT_OPACITY {
                    hit_depth = ndc_depth(near_h, far_h, origin, dir, t);
                }
                if acc.w > EARLY_EXIT_ALPHA {
                    break;
                }
            }
            (front_f, front_m) = (back_f, back_m);
        }
        return (acc, hit_depth);
    }
    for k in 0..u.max_steps {
        let t = t_enter + (k as f32 + jitter) * u.step_mm;
        if t >= t_far {
            break;
        }
        let x = origin + t * dir;
        let f = if use_fixed { classify(fixed, u, &u.fixed, tfs, x, light) } else { Vec4::ZERO };
        let m = if use_moving { classify(moving, u, &u.moving, tfs, x, light) } else { Vec4::ZERO };
        acc += (1.0 - acc.w) * blend(u, f, m, x);
        if hit_depth == NO_HIT_DEPTH && acc.w >= HIT_OPACITY {
            hit_depth = ndc_depth(near_h, far_h, origin, dir, t);
        }
        if acc.w > EARLY_EXIT_ALPHA {
            break;
        }
    }
    (acc, hit_depth)
}

/// The first-hit depth image of [`render`] (what [`crate::RenderTarget::read_hit_depth`] returns).
#[must_use]
pub fn render_hit_depth(
    u: &RaycastUniforms,
    fixed: &CpuLayer<'_>,
    moving: &CpuLayer<'_>,
    tfs: &[TransferFunction],
) -> Vec<f32> {
    let (w, h) = (u.viewport_px[0] as u32, u.viewport_px[1] as u32);
    let tables = preintegration_tables(u, tfs);
    (0..h)
        .flat_map(|y| (0..w).map(move |x| [x as f32 + 0.5, y as f32 + 0.5]))
        .map(|centre| shade_pixel_with_tables(u, fixed, moving, tfs, tables.as_ref(), centre).1)
        .collect()
}

/// The whole image as premultiplied RGBA8, rows top to bottom (what [`crate::RenderTarget::read_back`] returns).
#[must_use]
pub fn render(u: &RaycastUniforms, fixed: &CpuLayer<'_>, moving: &CpuLayer<'_>, tfs: &[TransferFunction]) -> Vec<u8> {
    render_rows(u, fixed, moving, tfs, 0..u.viewport_px[1] as u32)
}

/// Rows `rows` of [`render`]'s image (callers may split an image across threads).
#[must_use]
pub fn render_rows(
    u: &RaycastUniforms,
    fixed: &CpuLayer<'_>,
    moving: &CpuLayer<'_>,
    tfs: &[TransferFunction],
    rows: std::ops::Range<u32>,
) -> Vec<u8> {
    let tables = preintegration_tables(u, tfs);
    rasterise(u, rows, |centre| shade_pixel_with_tables(u, fixed, moving, tfs, tables.as_ref(), centre).0)
}

/// Rows `rows` of a `viewport_px`-wide image as RGBA8, each pixel from `pixel` at its centre (x + ½, y + ½),
/// quantised as the render target stores it.
fn rasterise(u: &RaycastUniforms, rows: std::ops::Range<u32>, pixel: impl Fn([f32; 2]) -> Vec4) -> Vec<u8> {
    let w = u.viewport_px[0] as u32;
    let mut out = Vec::with_capacity((4 * w * rows.len() as u32) as usize);
    for y in rows {
        for x in 0..w {
            let c = pixel([x as f32 + 0.5, y as f32 + 0.5]);
            out.extend(c.to_array().map(|v| (v.clamp(0.0, 1.0) * 255.0).round() as u8));
        }
    }
    out
}

/// The shader's `cs_pick` for one ray ([`crate::pick`]): marches `ray` through the target layer of the frame `u`
/// (its box and step, no jitter) and returns the probe's first hit, refined by bisection. A pre-integrating frame
/// builds its tables on each call: for many rays use [`pick_with_tables`].
#[must_use]
pub fn pick(
    u: &RaycastUniforms,
    fixed: &CpuLayer<'_>,
    moving: &CpuLayer<'_>,
    tfs: &[TransferFunction],
    request: &PickRequest,
    ray: &PickRay,
) -> PickHit {
    let tables = match request.probe {
        Probe::Accumulated { .. } => preintegration_tables(u, tfs),
        _ => None,
    };
    pick_with_tables(u, fixed, moving, tfs, tables.as_ref(), request, ray)
}

/// [`pick`] with the frame's pre-integration tables built once by the caller ([`preintegration_tables`]).
#[must_use]
pub fn pick_with_tables(
    u: &RaycastUniforms,
    fixed: &CpuLayer<'_>,
    moving: &CpuLayer<'_>,
    tfs: &[TransferFunction],
    tables: Option<&[PreIntegrationTable; 2]>,
    request: &PickRequest,
    ray: &PickRay,
) -> PickHit {
    let (layer, v, table) = match request.target {
        PickTarget::Fixed => (fixed, &u.fixed, tables.map(|t| &t[0])),
        PickTarget::Moving => (moving, &u.moving, tables.map(|t| &t[1])),
    };
    // A pick filters every lookup by hand, with exact weights, on the GPU too.
    let layer = &layer.with_filtering(FilterPrecision::EXACT);
    let threshold = request.probe.threshold();
    let accumulated = matches!(request.probe, Probe::Accumulated { .. });
    if accumulated
        && u.flags & RAYCAST_PREINTEGRATED != 0
        && let Some(table) = table
    {
        return pick_preintegrated(u, layer, v, table, request, ray);
    }
    let quantity = |x: Vec3| -> f32 {
        let p_tex = warp_to_tex(layer, v, x);
        if outside_tex(p_tex) {
            return 0.0;
        }
        if let Probe::Gradient { .. } = request.probe {
            return v.value_scale.abs() * warped_gradient(layer, u, v, x).length();
        }
        let t = ((volume_value(layer, v, p_tex) - v.window_low) / v.window_width).clamp(0.0, 1.0);
        (tf_sample(tfs, v.tf_row, t).w * v.opacity_scale).clamp(0.0, 1.0)
    };
    let accumulate = |acc: f32, alpha: f32, len_mm: f32| {
        acc + (1.0 - acc) * (1.0 - (len_mm / u.ref_step_mm * (1.0 - alpha).max(1e-7).log2()).exp2())
    };
    let (origin, dir) = (Vec3::from_array(ray.origin_ref), Vec3::from_array(ray.dir_ref));
    let miss = PickHit::miss(request.target);
    let Some((t_enter, t_far)) = proxy_span(u, origin, dir) else { return miss };
    let (mut t_prev, mut acc) = (-1.0f32, 0.0f32);
    for k in 0..u.max_steps {
        let t = t_enter + k as f32 * u.step_mm;
        if t >= t_far {
            break;
        }
        let q = quantity(origin + t * dir);
        let found = if accumulated { accumulate(acc, q, u.step_mm) >= threshold } else { q >= threshold };
        if found {
            let (mut t_hit, mut t_inside) = (t, t);
            if t_prev >= 0.0 {
                let (mut lo, mut hi) = (t_prev, t);
                for _ in 0..request.bisection_steps.min(32) {
                    let mid = 0.5 * (lo + hi);
                    let qm = quantity(origin + mid * dir);
                    let inside =
                        if accumulated { accumulate(acc, qm, mid - t_prev) >= threshold } else { qm >= threshold };
                    if inside {
                        hi = mid;
                    } else {
                        lo = mid;
                    }
                }
                (t_hit, t_inside) = (0.5 * (lo + hi), hi);
            }
            return hit_at(layer, v, request, (origin, dir), t_hit, t_inside);
        }
        if accumulated {
            acc = accumulate(acc, q, u.step_mm);
        }
        t_prev = t;
    }
    miss
}

/// The shader's `pick_hit_at`: the hit at ray parameter `t_hit` of the ray (origin, direction), the point pulled back
/// into the volume's LPS space and its value there; where a view deformation shows nothing at `t_hit` (the leafer's
/// opening), at `t_inside` instead (the bisection's upper end, on the face).
fn hit_at(
    layer: &CpuLayer<'_>,
    v: &VolumeUniforms,
    request: &PickRequest,
    (origin, dir): (Vec3, Vec3),
    t_hit: f32,
    t_inside: f32,
) -> PickHit {
    let empty = v.view.kind != VIEW_NONE && v.view.pullback(origin + t_hit * dir).x == VIEW_EMPTY;
    let t = if empty { t_inside } else { t_hit };
    let x_ref = origin + t * dir;
    let p_lps = pullback_lps(layer, v, x_ref);
    PickHit::new(request.target, x_ref, t, p_lps, volume_value(layer, v, data_tex(v, p_lps)))
}

/// The shader's `pick_march_preintegrated`: the accumulated probe, segment by segment as the frame composites.
fn pick_preintegrated(
    u: &RaycastUniforms,
    layer: &CpuLayer<'_>,
    v: &VolumeUniforms,
    table: &PreIntegrationTable,
    request: &PickRequest,
    ray: &PickRay,
) -> PickHit {
    let threshold = request.probe.threshold();
    let (origin, dir) = (Vec3::from_array(ray.origin_ref), Vec3::from_array(ray.dir_ref));
    let miss = PickHit::miss(request.target);
    let Some((t_enter, t_far)) = proxy_span(u, origin, dir) else { return miss };
    let segment_alpha = |front: f32, back: f32| {
        if front >= 0.0 && back >= 0.0 { table.sample(front, back)[3] } else { 0.0 }
    };
    let (mut acc, mut t_prev, mut front) = (0.0f32, t_enter, -1.0f32);
    for k in 0..u.max_steps {
        let t = t_enter + k as f32 * u.step_mm;
        if t >= t_far {
            break;
        }
        let back = tf_coord_at(layer, v, origin + t * dir);
        if k > 0 {
            let alpha = segment_alpha(front, back);
            if acc + (1.0 - acc) * alpha >= threshold {
                let (mut lo, mut hi) = (t_prev, t);
                for _ in 0..request.bisection_steps.min(32) {
                    let mid = 0.5 * (lo + hi);
                    let a = segment_alpha(front, tf_coord_at(layer, v, origin + mid * dir));
                    let part = 1.0 - ((mid - t_prev) / u.step_mm * (1.0 - a).max(1e-7).log2()).exp2();
                    if acc + (1.0 - acc) * part >= threshold {
                        hi = mid;
                    } else {
                        lo = mid;
                    }
                }
                return hit_at(layer, v, request, (origin, dir), 0.5 * (lo + hi), hi);
            }
            acc += (1.0 - acc) * alpha;
        }
        front = back;
        t_prev = t;
    }
    miss
}

/// The glyph pass ([`crate::glyph`], `shaders/glyph.wgsl`) over `image` (premultiplied RGBA8, `viewport_px`
/// big, rows top to bottom), in instance order, each write quantised as the render target stores it. `hit_depth` is
/// the frame's first-hit depth ([`render_hit_depth`]) in the 3-D view (empty: no hit anywhere, like the GPU pass
/// without a frame's hit depth) and ignored for slices.
pub fn composite_glyphs(u: &GlyphUniforms, glyphs: &[GlyphInstance], hit_depth: &[f32], image: &mut [u8]) {
    let (w, h) = (u.viewport_px[0] as i64, u.viewport_px[1] as i64);
    let clip_from_ref = Mat4::from_cols_array_2d(&u.clip_from_ref);
    let ref_from_clip = Mat4::from_cols_array_2d(&u.ref_from_clip);
    let project = |p: Vec3| -> Option<Vec3> {
        let clip = clip_from_ref * p.extend(1.0);
        if clip.w <= 0.0 {
            return None;
        }
        let ndc = clip.truncate() / clip.w;
        Some(Vec3::new((ndc.x + 1.0) * 0.5 * u.viewport_px[0], (1.0 - ndc.y) * 0.5 * u.viewport_px[1], ndc.z))
    };
    let ray_distance = |ndc: glam::Vec2, z: f32| {
        let near_h = ref_from_clip * Vec4::new(ndc.x, ndc.y, 0.0, 1.0);
        let p_h = ref_from_clip * Vec4::new(ndc.x, ndc.y, z, 1.0);
        (p_h.truncate() / p_h.w).distance(near_h.truncate() / near_h.w)
    };
    for glyph in glyphs {
        let (mut a, mut b) = (Vec3::from_array(glyph.a_ref), Vec3::from_array(glyph.b_ref));
        let mut radius = glyph.radius_px;
        if u.mode == GLYPH_MODE_SLICE {
            let n = Vec3::from_array(u.plane_normal_ref);
            let (da, db) = (n.dot(a) - u.plane_offset_mm, n.dot(b) - u.plane_offset_mm);
            if glyph.kind == KIND_POINT {
                let q = da / u.slab_half_mm;
                if q.abs() > 1.0 {
                    continue;
                }
                radius *= (1.0 - q * q).sqrt();
            } else {
                let (mut s0, mut s1) = (0.0f32, 1.0f32);
                let dd = db - da;
                if dd.abs() < 1e-12 {
                    if da.abs() > u.slab_half_mm {
                        continue;
                    }
                } else {
                    let (lo, hi) = ((-u.slab_half_mm - da) / dd, (u.slab_half_mm - da) / dd);
                    s0 = s0.max(lo.min(hi));
                    s1 = s1.min(lo.max(hi));
                    if s0 > s1 {
                        continue;
                    }
                }
                let e = b - a;
                (a, b) = (a + s0 * e, a + s1 * e);
            }
        }
        let (Some(pa), Some(pb)) = (project(a), project(b)) else { continue };
        if pa.z < 0.0 || pb.z < 0.0 || radius <= 0.0 {
            continue;
        }
        let e = pb.truncate() - pa.truncate();
        let len_sq = e.dot(e);
        let reach = radius + 1.0;
        let x_range =
            (pa.x.min(pb.x) - reach).floor().max(0.0) as i64..=((pa.x.max(pb.x) + reach).ceil() as i64).min(w - 1);
        let y_range =
            (pa.y.min(pb.y) - reach).floor().max(0.0) as i64..=((pa.y.max(pb.y) + reach).ceil() as i64).min(h - 1);
        for y in y_range {
            for x in x_range.clone() {
                let p = glam::Vec2::new(x as f32 + 0.5, y as f32 + 0.5);
                let s = if len_sq > 1e-12 { ((p - pa.truncate()).dot(e) / len_sq).clamp(0.0, 1.0) } else { 0.0 };
                let dist = p.distance(pa.truncate() + s * e);
                let coverage = (radius + 0.5 - dist).clamp(0.0, 1.0);
                if coverage <= 0.0 {
                    continue;
                }
                let mut rgb = Vec3::new(glyph.colour[0], glyph.colour[1], glyph.colour[2]);
                if glyph.kind == KIND_POINT {
                    let rim = (dist - (radius - u.outline_px) + 0.5).clamp(0.0, 1.0);
                    rgb = rgb.lerp(Vec3::ZERO, rim);
                }
                let mut alpha = glyph.colour[3] * coverage;
                let i = (y * w + x) as usize;
                if u.mode == GLYPH_MODE_VIEW {
                    let hit = hit_depth.get(i).copied().unwrap_or(NO_HIT_DEPTH);
                    if hit <= 1.0 {
                        let ndc =
                            glam::Vec2::new(p.x / u.viewport_px[0] * 2.0 - 1.0, 1.0 - p.y / u.viewport_px[1] * 2.0);
                        let z = pa.z + s * (pb.z - pa.z);
                        if ray_distance(ndc, z) > ray_distance(ndc, hit) + u.depth_tolerance_mm {
                            alpha *= u.occluded_alpha;
                        }
                    }
                }
                if alpha <= 0.0 {
                    continue;
                }
                let src = (rgb * alpha).extend(alpha);
                let px = &mut image[4 * i..4 * i + 4];
                let dst = Vec4::from_array(std::array::from_fn(|c| f32::from(px[c]) / 255.0));
                let out = src + dst * (1.0 - alpha);
                for (c, v) in px.iter_mut().zip(out.to_array()) {
                    *c = (v.clamp(0.0, 1.0) * 255.0).round() as u8;
                }
            }
        }
    }
}

/// The shader's `slice_sample`: the TF colour of one volume at `x_ref`, opaque inside its texture box, transparent
/// outside (see [`crate::slice`]).
#[must_use]
pub fn slice_sample(layer: &CpuLayer<'_>, v: &VolumeUniforms, tfs: &[TransferFunction], x_ref: Vec3) -> Vec4 {
    let p_tex = warp_to_tex(layer, v, x_ref);
    if outside_tex(p_tex) {
        return Vec4::ZERO;
    }
    let value = volume_value(layer, v, p_tex);
    let t = ((value - v.window_low) / v.window_width).clamp(0.0, 1.0);
    tf_sample(tfs, v.tf_row, t).truncate().extend(1.0)
}

/// The shader's `slice_pixel` (`cs_slice`): premultiplied RGBA (not yet quantised) of the slice pixel whose centre is at
/// `pixel_centre` (framebuffer coordinates, (px + ½, py + ½)), with `u` from [`RaycastUniforms::for_slice`].
#[must_use]
pub fn slice_pixel(
    u: &RaycastUniforms,
    fixed: &CpuLayer<'_>,
    moving: &CpuLayer<'_>,
    tfs: &[TransferFunction],
    pixel_centre: [f32; 2],
) -> Vec4 {
    let x = Mat4::from_cols_array_2d(&u.ref_from_frag_px).transform_point3(Vec3::new(
        pixel_centre[0],
        pixel_centre[1],
        0.0,
    ));
    let f = if u.fixed.flags & VOLUME_VISIBLE != 0 && u.blend_mode != 6 {
        slice_sample(fixed, &u.fixed, tfs, x)
    } else {
        Vec4::ZERO
    };
    let m = if u.moving.flags & VOLUME_VISIBLE != 0 && u.blend_mode != 5 {
        slice_sample(moving, &u.moving, tfs, x)
    } else {
        Vec4::ZERO
    };
    blend(u, f, m, x)
}

/// The whole slice as premultiplied RGBA8, rows top to bottom (what [`crate::RaycastRenderer::render_slice`] draws).
#[must_use]
pub fn render_slice(
    u: &RaycastUniforms,
    fixed: &CpuLayer<'_>,
    moving: &CpuLayer<'_>,
    tfs: &[TransferFunction],
) -> Vec<u8> {
    rasterise(u, 0..u.viewport_px[1] as u32, |centre| slice_pixel(u, fixed, moving, tfs, centre))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::{OrbitCamera, Projection};
    use crate::device::Capabilities;
    use crate::settings::{BlendMode, LayerParams, LayerStyle, Quality, RenderSettings};
    use crate::transfer::{TF_ENTRIES, Window};
    use crate::volume::{VolumeBudget, VolumeDesc, VolumeSamples};

    const CAPS: Capabilities = Capabilities { norm16: true, float32_filterable: true };
    const BUDGET: VolumeBudget = VolumeBudget { max_dimension: 4096, max_bytes: 1 << 30 };

    /// An n³ volume of constant `value` with 1 mm voxels whose voxel-edge box is [−n/2, n/2]³.
    fn constant_volume(n: usize, value: f32) -> PreparedVolume {
        let samples = vec![value; n * n * n];
        let o = -(n as f64) / 2.0 + 0.5;
        let lps_from_index = [[1.0, 0.0, 0.0, o], [0.0, 1.0, 0.0, o], [0.0, 0.0, 1.0, o], [0.0, 0.0, 0.0, 1.0]];
        let desc = VolumeDesc { dims: [n; 3], samples: VolumeSamples::F32(&samples), lps_from_index };
        PreparedVolume::prepare(&desc, CAPS, BUDGET).expect("prepare")
    }

    fn flat_tf(rgba: [u8; 4]) -> TransferFunction {
        TransferFunction { name: "flat".into(), entries: vec![rgba; TF_ENTRIES] }
    }

    fn style(visible: bool) -> LayerStyle {
        LayerStyle { window: Window::from_range(0.0, 1.0), tf_row: 0, opacity_scale: 1.0, visible, iso_value: 0.5 }
    }

    /// A constant volume with a flat TF of opacity α per reference step: after L mm the accumulated opacity is
    /// 1 − (1 − α)^(L / ref_step), whatever the step (opacity correction), and the colour is c·(that).
    #[test]
    fn constant_volume_gives_closed_form_opacity() {
        let vol = constant_volume(8, 0.5);
        let tfs = [flat_tf([255, 128, 0, 26])]; // α = 26/255 ≈ 0.102 per mm
        let alpha = 26.0f32 / 255.0;
        let layer = LayerParams {
            volume: vol.info,
            control: None,
            style: style(true),
            has_prefilter: false,
            procedural: None,
            view: None,
        };
        let hidden = LayerParams { style: style(false), ..layer };
        let cam = OrbitCamera::fit(Vec3::splat(-4.0), Vec3::splat(4.0), Projection::Orthographic);
        for spv in [1.0f32, 2.0, 4.0] {
            let settings = RenderSettings { blend: BlendMode::FixedOnly, samples_per_voxel: spv, ..Default::default() };
            let u = RaycastUniforms::new(&cam, &settings, (9, 9), &layer, &hidden, 1);
            let cpu = CpuLayer::new(&vol, None, None);
            // The centre ray crosses the whole 8 mm cube along +y: 8·spv samples of step 1/spv mm.
            let c = shade_pixel(&u, &cpu, &cpu, &tfs, [4.5, 4.5]);
            let expected = 1.0 - (1.0 - alpha).powf(8.0);
            assert!((c.w - expected).abs() < 2e-4, "spv {spv}: α {} vs {expected}", c.w);
            assert!((c.x - c.w).abs() < 1e-5 && (c.y - c.w * 128.0 / 255.0).abs() < 1e-4, "{c}");
        }
    }

    #[test]
    fn interactive_frames_sample_coarser_with_the_same_opacity() {
        let vol = constant_volume(8, 0.5);
        let tfs = [flat_tf([255, 128, 0, 26])];
        let layer = LayerParams {
            volume: vol.info,
            control: None,
            style: style(true),
            has_prefilter: false,
            procedural: None,
            view: None,
        };
        let hidden = LayerParams { style: style(false), ..layer };
        let cam = OrbitCamera::fit(Vec3::splat(-4.0), Vec3::splat(4.0), Projection::Orthographic);
        let cpu = CpuLayer::new(&vol, None, None);
        let settings = RenderSettings { blend: BlendMode::FixedOnly, samples_per_voxel: 2.0, ..Default::default() };
        let frame = |quality| {
            let u = RaycastUniforms::new(&cam, &settings.at(quality), (9, 9), &layer, &hidden, 1);
            (u.step_mm, shade_pixel(&u, &cpu, &cpu, &tfs, [4.5, 4.5]))
        };
        let (full_step, full) = frame(Quality::Full);
        let (fast_step, fast) = frame(Quality::Interactive);
        assert!((full_step - 0.5).abs() < 1e-6 && (fast_step - 2.0).abs() < 1e-6, "{full_step} {fast_step}");
        assert!((full - fast).abs().max_element() < 2e-4, "{full} vs {fast}");
        // Never finer than the full rate.
        let coarse = RenderSettings { samples_per_voxel: 0.25, ..settings };
        assert!((coarse.at(Quality::Interactive).samples_per_voxel - 0.25).abs() < f32::EPSILON);
    }

    #[test]
    fn outside_the_box_is_transparent_and_early_exit_stops_at_099() {
        let vol = constant_volume(8, 0.5);
        let tfs = [flat_tf([255, 255, 255, 255])];
        let layer = LayerParams {
            volume: vol.info,
            control: None,
            style: style(true),
            has_prefilter: false,
            procedural: None,
            view: None,
        };
        let cam = OrbitCamera::fit(Vec3::splat(-4.0), Vec3::splat(4.0), Projection::Orthographic);
        let settings = RenderSettings { blend: BlendMode::FixedOnly, ..Default::default() };
        let u = RaycastUniforms::new(&cam, &settings, (16, 16), &layer, &layer, 1);
        let cpu = CpuLayer::new(&vol, None, None);
        let img = render(&u, &cpu, &cpu, &tfs);
        // The view is 2·radius = 8√3 mm wide: the corner pixel misses the 8 mm cube.
        assert_eq!(&img[0..4], &[0, 0, 0, 0]);
        let centre = 4 * (8 * 16 + 8);
        assert_eq!(&img[centre..centre + 4], &[255, 255, 255, 255]);
    }

    #[test]
    fn a_constant_displacement_moves_the_sampled_point() {
        // Volume: value = x index ramp; control: +2 mm along x everywhere → sampled value grows by 2 voxels.
        let n = 8usize;
        let samples: Vec<f32> = (0..n * n * n).map(|i| (i % n) as f32).collect();
        let o = -(n as f64) / 2.0 + 0.5;
        let lps_from_index = [[1.0, 0.0, 0.0, o], [0.0, 1.0, 0.0, o], [0.0, 0.0, 1.0, o], [0.0, 0.0, 0.0, 1.0]];
        let desc = VolumeDesc { dims: [n; 3], samples: VolumeSamples::F32(&samples), lps_from_index };
        let vol = PreparedVolume::prepare(&desc, CAPS, BUDGET).expect("prepare");
        let texels: Vec<f32> = (0..8).flat_map(|_| [2.0, 0.0, 0.0, 0.0]).collect();
        let cdesc = crate::control::ControlDesc {
            dims: [2, 2, 2],
            texels: &texels,
            box_min_ref: [-4.0; 3],
            box_max_ref: [4.0; 3],
        };
        let ctrl = PreparedControl::prepare(&cdesc, true).expect("prepare");
        let tfs = [TransferFunction::from_points("ramp", &[(0.0, [0.0, 0.0, 0.0, 1.0]), (1.0, [1.0, 1.0, 1.0, 1.0])])];
        let st = LayerStyle { window: Window::from_range(0.0, 7.0), ..style(true) };
        let params = LayerParams {
            volume: vol.info,
            control: Some(ctrl.info),
            style: st,
            has_prefilter: false,
            procedural: None,
            view: None,
        };
        let cam = OrbitCamera::fit(Vec3::splat(-4.0), Vec3::splat(4.0), Projection::Orthographic);
        let u = RaycastUniforms::new(&cam, &RenderSettings::default(), (8, 8), &params, &params, 1);
        let layer = CpuLayer::new(&vol, Some(&ctrl), None);
        let x = Vec3::new(-0.5, 0.0, 0.0); // index 3 → value 3; warped to x = 1.5 → index 5
        let c = classify(&layer, &u, &u.fixed, &tfs, x, Vec3::Y);
        assert!((c.x - 5.0 / 7.0).abs() < 0.01, "{c}");
    }

    /// The gradient is taken through the warp: v(x) = x (a ramp along x, 1 mm voxels) pulled back through
    /// u(x) = x + d(x) with d = (x/2, 0, 0) near the origin (a 2³ control texture over [−4, 4]³, texel centres at
    /// ±2: trilinear reproduces the linear field between them) is v(u(x)) = 1.5·x, whose gradient is (1.5, 0, 0).
    /// And the headlight: n ∥ l gives colour·(ambient + diffuse) + specular; n ⊥ l gives colour·ambient.
    #[test]
    fn gradients_follow_the_warp_and_the_headlight_lights() {
        let n = 8usize;
        let o = -(n as f64) / 2.0 + 0.5;
        let samples: Vec<f32> = (0..n * n * n).map(|i| (i % n) as f32 + o as f32).collect();
        let lps_from_index = [[1.0, 0.0, 0.0, o], [0.0, 1.0, 0.0, o], [0.0, 0.0, 1.0, o], [0.0, 0.0, 0.0, 1.0]];
        let desc = VolumeDesc { dims: [n; 3], samples: VolumeSamples::F32(&samples), lps_from_index };
        let vol = PreparedVolume::prepare(&desc, CAPS, BUDGET).expect("prepare");
        let texels: Vec<f32> = (0..8).flat_map(|i| [if i & 1 == 0 { -1.0 } else { 1.0 }, 0.0, 0.0, 0.0]).collect();
        let cdesc = crate::control::ControlDesc {
            dims: [2, 2, 2],
            texels: &texels,
            box_min_ref: [-4.0; 3],
            box_max_ref: [4.0; 3],
        };
        let ctrl = PreparedControl::prepare(&cdesc, true).expect("prepare");
        let params = LayerParams {
            volume: vol.info,
            control: Some(ctrl.info),
            style: style(true),
            has_prefilter: false,
            procedural: None,
            view: None,
        };
        let cam = OrbitCamera::fit(Vec3::splat(-4.0), Vec3::splat(4.0), Projection::Orthographic);
        let u = RaycastUniforms::new(&cam, &RenderSettings::default(), (8, 8), &params, &params, 1);
        assert!((u.gradient_step_mm - 1.0).abs() < 1e-6, "h defaults to one voxel");
        let layer = CpuLayer::new(&vol, Some(&ctrl), None);
        let g = warped_gradient(&layer, &u, &u.fixed, Vec3::new(0.2, 0.1, -0.3));
        assert!((g - Vec3::new(1.5, 0.0, 0.0)).abs().max_element() < 1e-4, "{g}");
        let plain = CpuLayer { control: None, ..layer };
        let mut unwarped = u.fixed;
        unwarped.flags &= !VOLUME_HAS_WARP;
        let g = warped_gradient(&plain, &u, &unwarped, Vec3::new(0.2, 0.1, -0.3));
        assert!((g - Vec3::X).abs().max_element() < 1e-4, "{g}");

        let rgb = Vec3::new(0.5, 0.4, 0.2);
        let lit = shade(&u, rgb, Vec3::new(-3.0, 0.0, 0.0), Vec3::X);
        let expected = rgb * (u.ambient + u.diffuse) + Vec3::splat(u.specular);
        assert!((lit - expected.min(Vec3::ONE)).abs().max_element() < 1e-5, "{lit}");
        let side = shade(&u, rgb, Vec3::Y, Vec3::X);
        assert!((side - rgb * u.ambient).abs().max_element() < 1e-5, "{side}");
    }

    /// Pre-integration is exact for values linear along the ray (Engel et al. 2001): a ramp v = x index, seen along
    /// −x (trilinear is then linear between samples), through a transfer function with a thin opaque band in value
    /// (1.5 voxels wide, the kind that draws rings). At one sample per voxel, per-sample classification changes with
    /// where the samples fall (the rings: the camera moved by a fraction of a voxel along the ray), pre-integration
    /// does not and matches per-sample classification at 64 samples per voxel (the integral) to the table's accuracy.
    #[test]
    fn preintegration_is_exact_for_linear_data_where_per_sample_rings() {
        use crate::settings::Classification;
        let n = 16usize;
        let o = -(n as f64) / 2.0 + 0.5;
        let samples: Vec<f32> = (0..n * n * n).map(|i| (i % n) as f32).collect();
        let lps_from_index = [[1.0, 0.0, 0.0, o], [0.0, 1.0, 0.0, o], [0.0, 0.0, 1.0, o], [0.0, 0.0, 0.0, 1.0]];
        let desc = VolumeDesc { dims: [n; 3], samples: VolumeSamples::F32(&samples), lps_from_index };
        let vol = PreparedVolume::prepare(&desc, CAPS, BUDGET).expect("prepare");
        let band = TransferFunction::from_points(
            "band",
            &[
                (0.0, [0.0, 0.0, 0.0, 0.0]),
                (0.45, [0.2, 0.4, 1.0, 0.0]),
                (0.5, [1.0, 0.8, 0.4, 0.8]),
                (0.55, [0.2, 1.0, 0.2, 0.0]),
                (1.0, [0.0, 0.0, 0.0, 0.0]),
            ],
        );
        let tfs = [band];
        let st = LayerStyle { window: Window::from_range(0.0, 15.0), ..style(true) };
        let layer = LayerParams {
            volume: vol.info,
            control: None,
            style: st,
            has_prefilter: false,
            procedural: None,
            view: None,
        };
        let hidden = LayerParams { style: style(false), ..layer };
        let cpu = CpuLayer::new(&vol, None, None);
        let pixel = |classification, spv: f32, shift_mm: f32| {
            let cam = OrbitCamera::fit(Vec3::splat(-8.0), Vec3::splat(8.0), Projection::Orthographic);
            let cam = OrbitCamera { azimuth_rad: std::f32::consts::FRAC_PI_2, ..cam };
            let settings = RenderSettings {
                blend: BlendMode::FixedOnly,
                samples_per_voxel: spv,
                classification,
                // The rays enter the proxy box at x = 8 + shift, where the lattice starts: the samples move along the ray.
                box_override_ref: Some((Vec3::splat(-8.0), Vec3::new(8.0 + shift_mm, 8.0, 8.0))),
                ..Default::default()
            };
            let u = RaycastUniforms::new(&cam, &settings, (9, 9), &layer, &hidden, 1);
            shade_pixel(&u, &cpu, &cpu, &tfs, [4.5, 4.5])
        };
        let (mut pre_worst, mut per_sample) = (0.0f32, Vec::new());
        for shift_mm in [0.0f32, 0.25, 0.5, 0.75] {
            let reference = pixel(Classification::PerSample, 64.0, shift_mm);
            let pre = pixel(Classification::PreIntegrated, 1.0, shift_mm);
            assert!(reference.w > 0.3, "the band is seen: {reference}");
            pre_worst = pre_worst.max((pre - reference).abs().max_element());
            per_sample.push(pixel(Classification::PerSample, 1.0, shift_mm));
        }
        let spread = per_sample.iter().map(|c| (*c - per_sample[0]).abs().max_element()).fold(0.0f32, f32::max);
        eprintln!("pre-integrated within {pre_worst} of 64 spv; per-sample at 1 spv spreads {spread} with the phase");
        assert!(pre_worst < 0.01, "pre-integrated off the integral by {pre_worst}");
        assert!(spread > 0.1, "per-sample classification should ring at 1 spv: spread {spread}");
    }

    #[test]
    fn hash_matches_known_values() {
        // A pinned value: the WGSL twin is checked against this function by the jittered GPU test.
        assert_eq!(pcg_hash(0), 129_708_002);
        assert_ne!(pcg_hash(1), pcg_hash(0));
    }
}
