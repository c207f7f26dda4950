//! Control textures: a sampled pull-back u(x) = x + disp(x) over a box of the ref space (Brunet et al. 2006
//! §3.3), uploaded as a 3-D texture of displacements.
//!
//! The layout is the solver's (`warpbench_solver::control`), passed here as plain data ([`ControlDesc`]): `[dx, dy,
//! dz, 0]` mm per texel, x fastest; texel (a, b, c) is centred at ctrl tex ((a+½)/n₀, (b+½)/n₁, (c+½)/n₂) over the
//! box [min, max] of ref (fixed LPS) space, so `ctrl_tex_from_ref · x = (x − min)/(max − min)` and the hardware's
//! trilinear, clamp-to-edge lookup is the solver's `ControlTexture::lookup_raw`.
//!
//! Format: `Rgba32Float` when the device can filter it (FLOAT32_FILTERABLE), else `Rgba16Float`. f16 has 11
//! significant bits, so a displacement d is stored within |d|·2⁻¹¹ (≤ 0.025 mm for displacements up to 50 mm; the
//! quantisation is [`ControlInfo::quantisation_mm`]). Displacements rather than absolute positions keep this small.
//! A volume without a control texture takes the identity fast path (a uniform flag; no lookup).

use glam::{DVec3, Mat4, Vec3};
use half::f16;

use crate::device::GpuContext;
use crate::error::{GpuError, Result};
use crate::sampling::trilinear;

/// A control texture as plain data.
#[derive(Clone, Copy, Debug)]
pub struct ControlDesc<'a> {
    pub dims: [usize; 3],
    /// 4 f32 per texel, `[dx, dy, dz, 0]` mm, x fastest.
    pub texels: &'a [f32],
    pub box_min_ref: [f64; 3],
    pub box_max_ref: [f64; 3],
}

/// What the ray caster needs to know about a control texture (no GPU resources).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ControlInfo {
    pub dims: [u32; 3],
    /// Ref mm → \[0, 1\]³ control-texture coordinates.
    pub ctrl_tex_from_ref: Mat4,
    pub box_min_ref: DVec3,
    pub box_max_ref: DVec3,
    /// Largest storage error of a displacement component (0 for f32).
    pub quantisation_mm: f32,
    /// Componentwise minimum and maximum of the stored displacements (mm). Trilinear interpolation with
    /// clamp-to-edge never leaves [min, max], so every x has d(x) in this range: the proxy box uses it.
    pub disp_min_mm: Vec3,
    pub disp_max_mm: Vec3,
}

/// A control texture ready for upload; `texels` already hold the values the GPU will see (rounded to f16 when the
/// format is `Rgba16Float`).
#[derive(Clone, Debug, PartialEq)]
pub struct PreparedControl {
    pub info: ControlInfo,
    pub format: wgpu::TextureFormat,
    pub texels: Vec<[f32; 4]>,
}

impl PreparedControl {
    /// Checks `desc` and chooses the format (`float32_filterable`: see the module docs).
    pub fn prepare(desc: &ControlDesc<'_>, float32_filterable: bool) -> Result<Self> {
        let n: usize = desc.dims.iter().product();
        if desc.dims.contains(&0) || desc.texels.len() != 4 * n {
            return Err(GpuError::InvalidInput(format!(
                "control texture dims {:?} need {} floats, got {}",
                desc.dims,
                4 * n,
                desc.texels.len()
            )));
        }
        let (min, max) = (DVec3::from_array(desc.box_min_ref), DVec3::from_array(desc.box_max_ref));
        let size = max - min;
        if !size.is_finite() || size.min_element() <= 0.0 {
            return Err(GpuError::InvalidInput(format!("control texture box {min} .. {max} is empty or not finite")));
        }
        let scale = size.recip();
        let ctrl_tex_from_ref =
            Mat4::from_scale_rotation_translation(scale.as_vec3(), glam::Quat::IDENTITY, (-min * scale).as_vec3());
        let (format, round): (_, fn(f32) -> f32) = if float32_filterable {
            (wgpu::TextureFormat::Rgba32Float, |x| x)
        } else {
            (wgpu::TextureFormat::Rgba16Float, |x| f16::from_f32(x).to_f32())
        };
        let texels: Vec<[f32; 4]> =
            desc.texels.chunks_exact(4).map(|c| [round(c[0]), round(c[1]), round(c[2]), 0.0]).collect();
        let quantisation_mm = desc
            .texels
            .chunks_exact(4)
            .zip(&texels)
            .flat_map(|(a, b)| (0..3).map(move |i| (a[i] - b[i]).abs()))
            .fold(0.0f32, f32::max);
        let (disp_min_mm, disp_max_mm) = texels
            .iter()
            .map(|c| Vec3::new(c[0], c[1], c[2]))
            .fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(lo, hi), d| (lo.min(d), hi.max(d)));
        if !disp_min_mm.is_finite() || !disp_max_mm.is_finite() {
            return Err(GpuError::InvalidInput("control texture has non-finite displacements".into()));
        }
        let info = ControlInfo {
            dims: desc.dims.map(|d| d as u32),
            ctrl_tex_from_ref,
            box_min_ref: min,
            box_max_ref: max,
            quantisation_mm,
            disp_min_mm,
            disp_max_mm,
        };
        Ok(Self { info, format, texels })
    }

    /// Trilinear, clamp-to-edge lookup of the displacement at `x_ref`: the GPU's filtered lookup, in f32.
    #[must_use]
    pub fn displacement(&self, x_ref: Vec3) -> Vec3 {
        let t = self.info.ctrl_tex_from_ref.transform_point3(x_ref);
        let d = trilinear(self.info.dims, t, |i| {
            let c = self.texels[i];
            glam::Vec4::from_array(c)
        });
        d.truncate()
    }
}

/// An uploaded control texture.
#[derive(Debug)]
pub struct GpuControlTexture {
    pub info: ControlInfo,
    pub texture: wgpu::Texture,
    pub view: wgpu::TextureView,
}

impl GpuControlTexture {
    #[must_use]
    pub fn upload(ctx: &GpuContext, prepared: &PreparedControl) -> Self {
        let [w, h, d] = prepared.info.dims;
        let bytes: Vec<u8> = if prepared.format == wgpu::TextureFormat::Rgba32Float {
            bytemuck::cast_slice(&prepared.texels).to_vec()
        } else {
            let halves: Vec<u16> = prepared.texels.iter().flatten().map(|&x| f16::from_f32(x).to_bits()).collect();
            bytemuck::cast_slice(&halves).to_vec()
        };
        Self::create(ctx, prepared.info, prepared.format, [w, h, d], &bytes)
    }

    /// A 1×1×1 zero texture, bound where a volume has no warp (its uniform flag skips the lookup).
    #[must_use]
    pub(crate) fn placeholder(ctx: &GpuContext) -> wgpu::TextureView {
        let info = ControlInfo {
            dims: [1, 1, 1],
            ctrl_tex_from_ref: Mat4::IDENTITY,
            box_min_ref: DVec3::ZERO,
            box_max_ref: DVec3::ONE,
            quantisation_mm: 0.0,
            disp_min_mm: Vec3::ZERO,
            disp_max_mm: Vec3::ZERO,
        };
        Self::create(ctx, info, wgpu::TextureFormat::Rgba16Float, [1, 1, 1], &[0u8; 8]).view
    }

    fn create(ctx: &GpuContext, info: ControlInfo, format: wgpu::TextureFormat, dims: [u32; 3], bytes: &[u8]) -> Self {
        let size = wgpu::Extent3d { width: dims[0], height: dims[1], depth_or_array_layers: dims[2] };
        let usage = wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST;
        let texture = ctx.texture_3d("control texture", dims, format, usage);
        let texel_bytes = if format == wgpu::TextureFormat::Rgba32Float { 16 } else { 8 };
        ctx.queue.write_texture(
            texture.as_image_copy(),
            bytes,
            wgpu::TexelCopyBufferLayout {
                offset: 0,
                bytes_per_row: Some(dims[0] * texel_bytes),
                rows_per_image: Some(dims[1]),
            },
            size,
        );
        let view = texture.create_view(&wgpu::TextureViewDescriptor::default());
        Self { info, texture, view }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn box_maps_to_unit_cube_and_constant_fields_are_reproduced() {
        let texels: Vec<f32> = (0..4 * 3 * 2).flat_map(|_| [1.5, -2.0, 0.25, 0.0]).collect();
        let desc = ControlDesc {
            dims: [4, 3, 2],
            texels: &texels,
            box_min_ref: [-10.0, 0.0, 5.0],
            box_max_ref: [10.0, 30.0, 9.0],
        };
        for f32_ok in [true, false] {
            let p = PreparedControl::prepare(&desc, f32_ok).expect("prepare");
            let t = p.info.ctrl_tex_from_ref.transform_point3(Vec3::new(10.0, 0.0, 7.0));
            assert!((t - Vec3::new(1.0, 0.0, 0.5)).abs().max_element() < 1e-6);
            let d = p.displacement(Vec3::new(3.0, 100.0, 6.0));
            assert!((d - Vec3::new(1.5, -2.0, 0.25)).abs().max_element() < 1e-6, "{d}");
        }
        assert!(PreparedControl::prepare(&ControlDesc { texels: &texels[4..], ..desc }, true).is_err());
    }

    #[test]
    fn f16_fallback_states_its_error() {
        let texels: Vec<f32> = (0..8).flat_map(|i| [i as f32 * 6.1, -0.1, 31.7, 0.0]).collect();
        let desc = ControlDesc { dims: [2, 2, 2], texels: &texels, box_min_ref: [0.0; 3], box_max_ref: [1.0; 3] };
        let p = PreparedControl::prepare(&desc, false).expect("prepare");
        assert_eq!(p.format, wgpu::TextureFormat::Rgba16Float);
        assert!(p.info.quantisation_mm > 0.0 && p.info.quantisation_mm <= 44.0 / 2048.0);
    }
}
