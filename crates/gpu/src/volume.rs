//! Volumes as 3-D textures, with the intensity mapping kept exact.
//!
//! A volume arrives as plain data ([`VolumeDesc`]: dims, samples x fastest, and the row-major 4×4 `lps_from_index`
//! with voxel centres at integer indices, as in ITK). [`PreparedVolume::prepare`] chooses the texture format and
//! the texel values on the CPU, so the GPU upload ([`GpuVolume::upload`]) and the CPU reference see the same texels.
//! The shader reads a normalised texel t and maps it back with `value = value_offset + value_scale · t`:
//!
//! | samples | format (device has …) | mapping | exactness |
//! |---|---|---|---|
//! | u8 | `R8Unorm` (16BIT_NORM) | 255 · t | exact |
//! | i16 | `R16Unorm` (16BIT_NORM) | −32768 + 65535 · t | every i16 representable (HU exact); the f32 evaluation is within 0.004 |
//! | u16 | `R16Unorm` (16BIT_NORM) | 65535 · t | as for i16 |
//! | f32 | `R32Float` (FLOAT32_FILTERABLE) | t | exact |
//! | f32 | `R16Unorm` (16BIT_NORM only) | lo + (hi − lo) · t over the finite range | error ≤ (hi − lo)/131070: 0.03 HU for a 4000 HU CT range |
//! | any | `R32Float` (no 16BIT_NORM) | t | exact; filtered by hand in the shader when the format cannot be filtered |
//!
//! `R16Float` is never used: it holds integers exactly only up to 2048. Non-finite f32 samples become the lowest
//! finite value. Volumes larger than the device's `max_texture_dimension_3d` or a memory budget are box-filtered down
//! by an integer factor per axis, with a warning that names the factors ([`PreparedVolume::warnings`]).
//!
//! Each volume carries `tex_from_lps` = `tex_from_index · index_from_lps`, with tex = (index + ½)/dims, so that
//! \[0, 1\]³ is the box of voxel edges.

use glam::{DMat4, DVec3, DVec4, Mat4};

use crate::device::{Capabilities, GpuContext};
use crate::error::{GpuError, Result};

/// Borrowed voxel samples, x fastest.
#[derive(Clone, Copy, Debug)]
pub enum VolumeSamples<'a> {
    U8(&'a [u8]),
    I16(&'a [i16]),
    U16(&'a [u16]),
    F32(&'a [f32]),
}

impl VolumeSamples<'_> {
    #[must_use]
    pub fn len(&self) -> usize {
        match self {
            Self::U8(v) => v.len(),
            Self::I16(v) => v.len(),
            Self::U16(v) => v.len(),
            Self::F32(v) => v.len(),
        }
    }
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
    fn get(&self, i: usize) -> f64 {
        match self {
            Self::U8(v) => f64::from(v[i]),
            Self::I16(v) => f64::from(v[i]),
            Self::U16(v) => f64::from(v[i]),
            Self::F32(v) => f64::from(v[i]),
        }
    }
    fn is_integer(&self) -> bool {
        !matches!(self, Self::F32(_))
    }
}

/// A volume as plain data: what the `io` crate's `Volume` holds, without depending on it.
#[derive(Clone, Copy, Debug)]
pub struct VolumeDesc<'a> {
    pub dims: [usize; 3],
    pub samples: VolumeSamples<'a>,
    /// Row-major 4×4 affine from continuous voxel index (0 = centre of the first voxel) to LPS mm.
    pub lps_from_index: [[f64; 4]; 4],
}

/// Limits on what is uploaded: larger volumes are downsampled.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct VolumeBudget {
    pub max_dimension: u32,
    pub max_bytes: u64,
}

impl VolumeBudget {
    /// Default texture memory per volume.
    pub const DEFAULT_MAX_BYTES: u64 = 1 << 30;

    /// The device's 3-D texture limit and [`Self::DEFAULT_MAX_BYTES`].
    #[must_use]
    pub fn for_device(limits: &wgpu::Limits) -> Self {
        Self { max_dimension: limits.max_texture_dimension_3d, max_bytes: Self::DEFAULT_MAX_BYTES }
    }
}

/// Texel storage, in the texture's own format.
#[derive(Clone, Debug, PartialEq)]
pub enum Texels {
    R8Unorm(Vec<u8>),
    R16Unorm(Vec<u16>),
    R32Float(Vec<f32>),
}

impl Texels {
    #[must_use]
    pub fn format(&self) -> wgpu::TextureFormat {
        match self {
            Self::R8Unorm(_) => wgpu::TextureFormat::R8Unorm,
            Self::R16Unorm(_) => wgpu::TextureFormat::R16Unorm,
            Self::R32Float(_) => wgpu::TextureFormat::R32Float,
        }
    }
    fn bytes(&self) -> &[u8] {
        match self {
            Self::R8Unorm(v) => v,
            Self::R16Unorm(v) => bytemuck::cast_slice(v),
            Self::R32Float(v) => bytemuck::cast_slice(v),
        }
    }
    fn bytes_per_texel(&self) -> u32 {
        match self {
            Self::R8Unorm(_) => 1,
            Self::R16Unorm(_) => 2,
            Self::R32Float(_) => 4,
        }
    }
    /// The normalised value the shader reads for texel `i`.
    #[must_use]
    pub fn normalised(&self, i: usize) -> f32 {
        match self {
            Self::R8Unorm(v) => f32::from(v[i]) / 255.0,
            Self::R16Unorm(v) => f32::from(v[i]) / 65535.0,
            Self::R32Float(v) => v[i],
        }
    }
}

/// What the ray caster needs to know about an uploaded volume (no GPU resources): shared by the GPU path and the
/// CPU reference.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct VolumeInfo {
    /// Texture size (after any downsampling).
    pub dims: [u32; 3],
    pub value_offset: f32,
    pub value_scale: f32,
    /// LPS mm → \[0, 1\]³ texture coordinates.
    pub tex_from_lps: Mat4,
    /// Index (of the texture) → LPS mm.
    pub lps_from_index: DMat4,
    pub spacing_mm: [f64; 3],
    /// Axis-aligned LPS box around the voxel-edge box (its 8 corners).
    pub box_min_lps: DVec3,
    pub box_max_lps: DVec3,
    /// The shader filters by hand (format not filterable on this device).
    pub manual_filter: bool,
    /// Largest error of the stored value against the source sample, from quantisation (0 when exact).
    pub quantisation: f64,
}

/// A volume ready for upload: texels in the chosen format plus its [`VolumeInfo`].
#[derive(Clone, Debug, PartialEq)]
pub struct PreparedVolume {
    pub info: VolumeInfo,
    pub texels: Texels,
    /// Non-fatal changes made (downsampling), to show to the user.
    pub warnings: Vec<String>,
}

impl PreparedVolume {
    /// Chooses the format for `capabilities`, downsamples to fit `budget`, and converts the samples.
    pub fn prepare(desc: &VolumeDesc<'_>, capabilities: Capabilities, budget: VolumeBudget) -> Result<Self> {
        let n: usize = desc.dims.iter().try_fold(1usize, |a, &d| a.checked_mul(d)).unwrap_or(0);
        if desc.dims.contains(&0) || n != desc.samples.len() {
            return Err(GpuError::InvalidInput(format!(
                "volume dims {:?} need {n} samples, got {}",
                desc.dims,
                desc.samples.len()
            )));
        }
        let lps_from_index = DMat4::from_cols_array_2d(&desc.lps_from_index).transpose();
        if !lps_from_index.is_finite() || lps_from_index.determinant().abs() < 1e-12 {
            return Err(GpuError::InvalidInput(format!("lps_from_index is singular: {:?}", desc.lps_from_index)));
        }
        let bytes_per_sample: u64 = match (desc.samples, capabilities.norm16, capabilities.float32_filterable) {
            (VolumeSamples::U8(_), true, _) => 1,
            (VolumeSamples::I16(_) | VolumeSamples::U16(_), true, _) | (VolumeSamples::F32(_), true, false) => 2,
            _ => 4,
        };
        let mut warnings = Vec::new();
        let factors = downsample_factors(desc.dims, bytes_per_sample, budget);
        let (dims, values, lps_from_index) = if factors == [1, 1, 1] {
            (desc.dims, None, lps_from_index)
        } else {
            let (dims, values) = box_downsample(desc, factors);
            warnings.push(format!(
                "volume {}×{}×{} exceeds the GPU budget ({} texels per axis, {} MiB): downsampled by {}×{}×{} \
                 (box filter) to {}×{}×{}",
                desc.dims[0],
                desc.dims[1],
                desc.dims[2],
                budget.max_dimension,
                budget.max_bytes >> 20,
                factors[0],
                factors[1],
                factors[2],
                dims[0],
                dims[1],
                dims[2]
            ));
            let scale = DMat4::from_cols(
                DVec4::new(factors[0] as f64, 0.0, 0.0, 0.0),
                DVec4::new(0.0, factors[1] as f64, 0.0, 0.0),
                DVec4::new(0.0, 0.0, factors[2] as f64, 0.0),
                DVec4::new(
                    (factors[0] as f64 - 1.0) / 2.0,
                    (factors[1] as f64 - 1.0) / 2.0,
                    (factors[2] as f64 - 1.0) / 2.0,
                    1.0,
                ),
            );
            (dims, Some(values), lps_from_index * scale)
        };
        let count = dims.iter().product::<usize>();
        let sample = |i: usize| -> f64 { values.as_ref().map_or_else(|| desc.samples.get(i), |v| v[i]) };
        let (lo, hi) = (0..count)
            .map(sample)
            .filter(|v| v.is_finite())
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| (a.min(v), b.max(v)));
        let (lo, hi) = if lo.is_finite() { (lo, hi) } else { (0.0, 0.0) };
        let finite = |v: f64| if v.is_finite() { v } else { lo };

        let manual_filter = !capabilities.volumes_filterable();
        let (texels, value_offset, value_scale, quantisation) = match desc.samples {
            VolumeSamples::U8(_) if capabilities.norm16 => {
                (Texels::R8Unorm((0..count).map(|i| sample(i).round() as u8).collect()), 0.0, 255.0, 0.0)
            }
            VolumeSamples::I16(_) if capabilities.norm16 => (
                Texels::R16Unorm((0..count).map(|i| (sample(i).round() + 32768.0) as u16).collect()),
                -32768.0,
                65535.0,
                0.0,
            ),
            VolumeSamples::U16(_) if capabilities.norm16 => {
                (Texels::R16Unorm((0..count).map(|i| sample(i).round() as u16).collect()), 0.0, 65535.0, 0.0)
            }
            VolumeSamples::F32(_) if capabilities.norm16 && !capabilities.float32_filterable => {
                let range = (hi - lo).max(f64::MIN_POSITIVE);
                let texels =
                    (0..count).map(|i| ((finite(sample(i)) - lo) / range * 65535.0).round().clamp(0.0, 65535.0) as u16);
                (Texels::R16Unorm(texels.collect()), lo as f32, range as f32, range / 131_070.0)
            }
            _ => (Texels::R32Float((0..count).map(|i| finite(sample(i)) as f32).collect()), 0.0, 1.0, 0.0),
        };
        let quantisation =
            if values.is_some() && desc.samples.is_integer() { quantisation.max(0.5) } else { quantisation };

        let dims_u32 = dims.map(|d| d as u32);
        let index_from_tex = DMat4::from_cols(
            DVec4::new(dims[0] as f64, 0.0, 0.0, 0.0),
            DVec4::new(0.0, dims[1] as f64, 0.0, 0.0),
            DVec4::new(0.0, 0.0, dims[2] as f64, 0.0),
            DVec4::new(-0.5, -0.5, -0.5, 1.0),
        );
        let lps_from_tex = lps_from_index * index_from_tex;
        let tex_from_lps = lps_from_tex.inverse();
        let (mut box_min_lps, mut box_max_lps) = (DVec3::INFINITY, DVec3::NEG_INFINITY);
        for c in 0..8 {
            let corner = DVec3::new(f64::from(c & 1), f64::from((c >> 1) & 1), f64::from((c >> 2) & 1));
            let p = lps_from_tex.transform_point3(corner);
            box_min_lps = box_min_lps.min(p);
            box_max_lps = box_max_lps.max(p);
        }
        let spacing_mm = [0, 1, 2].map(|a| lps_from_index.col(a).truncate().length());
        let info = VolumeInfo {
            dims: dims_u32,
            value_offset,
            value_scale,
            tex_from_lps: tex_from_lps.as_mat4(),
            lps_from_index,
            spacing_mm,
            box_min_lps,
            box_max_lps,
            manual_filter,
            quantisation,
        };
        Ok(Self { info, texels, warnings })
    }

    /// The value the texture holds at texel `i` (after the offset/scale mapping), as the shader computes it.
    #[must_use]
    pub fn value(&self, i: usize) -> f32 {
        self.info.value_offset + self.info.value_scale * self.texels.normalised(i)
    }
}

/// Smallest integer factor per axis so that the box-filtered volume fits `budget`.
fn downsample_factors(dims: [usize; 3], bytes_per_sample: u64, budget: VolumeBudget) -> [usize; 3] {
    let mut f = [1usize; 3];
    let max_dim = budget.max_dimension.max(1) as usize;
    loop {
        let d = [0, 1, 2].map(|a| dims[a].div_ceil(f[a]));
        let bytes = d.iter().fold(bytes_per_sample, |acc, &x| acc.saturating_mul(x as u64));
        let too_big = bytes > budget.max_bytes;
        if d.iter().all(|&x| x <= max_dim) && !too_big {
            return f;
        }
        for a in 0..3 {
            if d[a] > max_dim || (too_big && d[a] > 1) {
                f[a] += 1;
            }
        }
    }
}

/// Box filter: output voxel a averages input voxels [a·f, min(a·f + f, n)) per axis (finite samples only).
fn box_downsample(desc: &VolumeDesc<'_>, f: [usize; 3]) -> ([usize; 3], Vec<f64>) {
    let [nx, ny, nz] = desc.dims;
    let out_dims = [0, 1, 2].map(|a| desc.dims[a].div_ceil(f[a]));
    let mut out = Vec::with_capacity(out_dims.iter().product());
    for c in 0..out_dims[2] {
        for b in 0..out_dims[1] {
            for a in 0..out_dims[0] {
                let (mut sum, mut count) = (0.0f64, 0u32);
                for k in c * f[2]..((c + 1) * f[2]).min(nz) {
                    for j in b * f[1]..((b + 1) * f[1]).min(ny) {
                        for i in a * f[0]..((a + 1) * f[0]).min(nx) {
                            let v = desc.samples.get(i + nx * (j + ny * k));
                            if v.is_finite() {
                                sum += v;
                                count += 1;
                            }
                        }
                    }
                }
                out.push(if count == 0 { f64::NAN } else { sum / f64::from(count) });
            }
        }
    }
    (out_dims, out)
}

/// An uploaded volume: the 3-D texture and its [`VolumeInfo`].
#[derive(Debug)]
pub struct GpuVolume {
    pub info: VolumeInfo,
    /// Min/max of the texels per brick, for empty-space skipping ([`crate::empty_space`]).
    pub bricks: VolumeBricks,
    pub texture: wgpu::Texture,
    pub view: wgpu::TextureView,
}

impl GpuVolume {
    /// Uploads `prepared` (which must have been prepared for this device's capabilities).
    pub fn upload(ctx: &GpuContext, prepared: &PreparedVolume) -> Result<Self> {
        let format = prepared.texels.format();
        if format == wgpu::TextureFormat::R16Unorm && !ctx.capabilities.norm16 {
            return Err(GpuError::InvalidInput("R16Unorm volume on a device without TEXTURE_FORMAT_16BIT_NORM".into()));
        }
        let [w, h, d] = prepared.info.dims;
        let size = wgpu::Extent3d { width: w, height: h, depth_or_array_layers: d };
        let texture = ctx.texture_3d(
            "volume",
            prepared.info.dims,
            format,
            wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
        );
        ctx.queue.write_texture(
            texture.as_image_copy(),
            prepared.texels.bytes(),
            wgpu::TexelCopyBufferLayout {
                offset: 0,
                bytes_per_row: Some(w * prepared.texels.bytes_per_texel()),
                rows_per_image: Some(h),
            },
            size,
        );
        let view = texture.create_view(&wgpu::TextureViewDescriptor::default());
        Ok(Self { info: prepared.info, bricks: VolumeBricks::of(prepared), texture, view })
    }
}

/// Edge of a volume brick ([`VolumeBricks`]), voxels.
pub const BRICK_VOXELS: usize = 8;

/// Min/max of a volume's normalised texels per brick of [`BRICK_VOXELS`]³ voxels, in its index space.
#[derive(Clone, Debug, PartialEq)]
pub struct VolumeBricks {
    /// Voxels per axis.
    pub voxel_dims: [u32; 3],
    /// Bricks per axis, ⌈voxel_dims / BRICK_VOXELS⌉.
    pub dims: [u32; 3],
    /// `[min, max]` per brick, x fastest.
    pub ranges: Vec<[f32; 2]>,
}

impl VolumeBricks {
    /// The bricks of `volume`'s texels, as uploaded (after any downsampling).
    #[must_use]
    pub fn of(volume: &PreparedVolume) -> Self {
        let voxel_dims = volume.info.dims;
        let [nx, ny, nz] = voxel_dims.map(|d| d as usize);
        let dims = voxel_dims.map(|d| (d as usize).div_ceil(BRICK_VOXELS) as u32);
        let [bx, by, _] = dims.map(|d| d as usize);
        let mut ranges = vec![[f32::INFINITY, f32::NEG_INFINITY]; dims.iter().map(|&d| d as usize).product()];
        for k in 0..nz {
            for j in 0..ny {
                let row = nx * (j + ny * k);
                let brick_row = bx * (j / BRICK_VOXELS + by * (k / BRICK_VOXELS));
                for (b, range) in ranges[brick_row..brick_row + bx].iter_mut().enumerate() {
                    let (lo, hi) = (row + b * BRICK_VOXELS, row + ((b + 1) * BRICK_VOXELS).min(nx));
                    for i in lo..hi {
                        let t = volume.texels.normalised(i);
                        range[0] = range[0].min(t);
                        range[1] = range[1].max(t);
                    }
                }
            }
        }
        Self { voxel_dims, dims, ranges }
    }

    /// Min/max of the texels with indices in `lo ..= hi` (clamped to the volume), or `None` for an empty range.
    #[must_use]
    pub fn range(&self, lo: [i64; 3], hi: [i64; 3]) -> Option<[f32; 2]> {
        let mut b0 = [0usize; 3];
        let mut b1 = [0usize; 3];
        for a in 0..3 {
            let last = i64::from(self.voxel_dims[a]) - 1;
            let (l, h) = (lo[a].clamp(0, last), hi[a].clamp(0, last));
            if l > h {
                return None;
            }
            (b0[a], b1[a]) = (l as usize / BRICK_VOXELS, h as usize / BRICK_VOXELS);
        }
        let [bx, by, _] = self.dims.map(|d| d as usize);
        let mut out = [f32::INFINITY, f32::NEG_INFINITY];
        for k in b0[2]..=b1[2] {
            for j in b0[1]..=b1[1] {
                for r in &self.ranges[bx * (j + by * k) + b0[0]..=bx * (j + by * k) + b1[0]] {
                    out = [out[0].min(r[0]), out[1].max(r[1])];
                }
            }
        }
        Some(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const ALL: Capabilities = Capabilities { norm16: true, float32_filterable: true };
    const BIG: VolumeBudget = VolumeBudget { max_dimension: 4096, max_bytes: 1 << 30 };
    const SCALE2: [[f64; 4]; 4] =
        [[2.0, 0.0, 0.0, -10.0], [0.0, 2.0, 0.0, 5.0], [0.0, 0.0, 3.0, 1.0], [0.0, 0.0, 0.0, 1.0]];

    #[test]
    fn every_i16_value_survives_r16unorm() {
        let samples: Vec<i16> = (i16::MIN..=i16::MAX).collect();
        let desc = VolumeDesc { dims: [256, 256, 1], samples: VolumeSamples::I16(&samples), lps_from_index: SCALE2 };
        let p = PreparedVolume::prepare(&desc, ALL, BIG).expect("prepare");
        assert_eq!(p.texels.format(), wgpu::TextureFormat::R16Unorm);
        let worst = (0..samples.len()).map(|i| (p.value(i) - f32::from(samples[i])).abs()).fold(0.0f32, f32::max);
        assert!(worst < 0.01, "worst {worst}");
    }

    #[test]
    fn tex_from_lps_puts_voxel_centres_at_half_texels() {
        let samples = vec![0u8; 4 * 5 * 6];
        let desc = VolumeDesc { dims: [4, 5, 6], samples: VolumeSamples::U8(&samples), lps_from_index: SCALE2 };
        let p = PreparedVolume::prepare(&desc, ALL, BIG).expect("prepare");
        let centre0 = p.info.lps_from_index.transform_point3(DVec3::ZERO).as_vec3();
        let t = p.info.tex_from_lps.transform_point3(centre0);
        assert!((t - glam::Vec3::new(0.125, 0.1, 1.0 / 12.0)).abs().max_element() < 1e-6, "{t}");
        assert!(p.info.spacing_mm.iter().zip([2.0, 2.0, 3.0]).all(|(a, b)| (a - b).abs() < 1e-12));
        assert!((p.info.box_min_lps - DVec3::new(-11.0, 4.0, -0.5)).abs().max_element() < 1e-12);
    }

    #[test]
    fn f32_without_float_filtering_is_r16unorm_over_the_range() {
        let samples: Vec<f32> = (0..1000).map(|i| -1024.0 + 3.1 * i as f32).collect();
        let desc = VolumeDesc { dims: [10, 10, 10], samples: VolumeSamples::F32(&samples), lps_from_index: SCALE2 };
        let caps = Capabilities { norm16: true, float32_filterable: false };
        let p = PreparedVolume::prepare(&desc, caps, BIG).expect("prepare");
        assert_eq!(p.texels.format(), wgpu::TextureFormat::R16Unorm);
        let worst = (0..1000).map(|i| (f64::from(p.value(i)) - f64::from(samples[i])).abs()).fold(0.0, f64::max);
        assert!(worst <= p.info.quantisation + 1e-3 && p.info.quantisation < 0.05, "{worst} {}", p.info.quantisation);
        let none = Capabilities { norm16: false, float32_filterable: false };
        let p = PreparedVolume::prepare(&desc, none, BIG).expect("prepare");
        assert!(p.info.manual_filter && p.texels.format() == wgpu::TextureFormat::R32Float);
    }

    #[test]
    fn oversized_volumes_are_box_filtered_with_a_warning() {
        let samples: Vec<u16> = (0..8 * 8 * 4).map(|i| (i % 8) as u16 * 10).collect();
        let desc = VolumeDesc { dims: [8, 8, 4], samples: VolumeSamples::U16(&samples), lps_from_index: SCALE2 };
        let budget = VolumeBudget { max_dimension: 4, max_bytes: 1 << 30 };
        let p = PreparedVolume::prepare(&desc, ALL, budget).expect("prepare");
        assert_eq!(p.info.dims, [4, 4, 4]);
        assert!(p.warnings[0].contains("2×2×1"), "{:?}", p.warnings);
        // Voxel 0 averages x = 0, 1 (values 0 and 10) and sits between their centres.
        assert!((p.value(0) - 5.0).abs() < 0.01);
        let c = p.info.lps_from_index.transform_point3(DVec3::ZERO);
        assert!((c - DVec3::new(-9.0, 6.0, 1.0)).abs().max_element() < 1e-12, "{c}");
        // The memory budget alone also forces downsampling.
        let budget = VolumeBudget { max_dimension: 4096, max_bytes: 100 };
        let p = PreparedVolume::prepare(&desc, ALL, budget).expect("prepare");
        assert!(p.info.dims.iter().map(|&d| u64::from(d)).product::<u64>() * 2 <= 100, "{:?}", p.info.dims);
    }

    #[test]
    fn bad_input_is_an_error() {
        let samples = vec![0u8; 10];
        let desc = VolumeDesc { dims: [4, 5, 6], samples: VolumeSamples::U8(&samples), lps_from_index: SCALE2 };
        assert!(PreparedVolume::prepare(&desc, ALL, BIG).is_err());
        let samples = vec![0u8; 120];
        let desc = VolumeDesc { dims: [4, 5, 6], samples: VolumeSamples::U8(&samples), lps_from_index: [[0.0; 4]; 4] };
        assert!(PreparedVolume::prepare(&desc, ALL, BIG).is_err());
    }
}
