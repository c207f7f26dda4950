//! How precisely this device's hardware trilinear filter weighs its texels ([`FilterPrecision`],
//! [`crate::sampling`]): Vulkan lets a device round each weight to 2⁻ᵇ with b as low as 4 (its
//! `subTexelPrecisionBits`), and NVIDIA, AMD and Intel GPUs use b = 8. The ray caster filters volumes and control
//! textures in hardware, so its images differ from the exact CPU reference by that rounding; the GPU tests derive
//! their tolerances from the measured b, and `data-scripts/gpu_check.sh` reports it.
//!
//! [`FilterProbe::measure`] samples a 2×1×1 texture holding 0 and 1 (in each format the ray caster filters in
//! hardware on this device) at [`FilterProbe::SAMPLES`] weights f = k/n between its texel centres
//! (`shaders/filter_probe.wgsl`). With those texels the filtered value is the weight as the device used it. The
//! coarsest grid 2⁻ᵇ that holds every value is the device's b; when the values need more than
//! [`FilterProbe::RESOLVED_BITS`] bits the filter is as fine as the probe can tell, and is reported as that many bits
//! (a test then still allows for rounding at that level). The direction of the rounding is the one of
//! [`WeightRounding`] that reproduces every value, or none. An `R8Unorm` texture whose every filtered value lies on
//! its 255 steps returns rounded results ([`FilterPrecision::unorm8_results`]); its weights are then not resolved
//! (the format's step hides them) and the other formats' bits stand for them.

use bytemuck::{Pod, Zeroable};

use crate::compute::{self, binding, storage, uniform};
use crate::device::GpuContext;
use crate::error::{GpuError, Result};
use crate::sampling::{FilterPrecision, WeightPrecision, WeightRounding};
use crate::shader::{BindSlot, ShaderInterface, ShaderSource, Stage, layout};

/// `shaders/filter_probe.wgsl`.
pub const SHADER: ShaderSource = ShaderSource {
    name: "filter_probe",
    path: "shaders/filter_probe.wgsl",
    source: include_str!("../../../shaders/filter_probe.wgsl"),
    entry_points: &[(FilterProbe::ENTRY_POINT, Stage::Compute)],
};

pub const SLOT_UNIFORMS: BindSlot = BindSlot::new(0, 0, "probe");
pub const SLOT_TEXTURE: BindSlot = BindSlot::new(0, 1, "probe_tex");
pub const SLOT_SAMPLER: BindSlot = BindSlot::new(0, 2, "probe_sampler");
pub const SLOT_OUTPUT: BindSlot = BindSlot::new(0, 3, "probe_out");

/// The probe's part of `shaders/filter_probe.wgsl`.
pub const INTERFACE: ShaderInterface = ShaderInterface {
    pass: "filter_probe",
    shader: SHADER,
    uniform_structs: &[layout!(ProbeUniforms { count })],
    slots: &[SLOT_UNIFORMS, SLOT_TEXTURE, SLOT_SAMPLER, SLOT_OUTPUT],
    constants: &[],
};

/// `ProbeUniforms` in shaders/filter_probe.wgsl.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq, Pod, Zeroable)]
pub struct ProbeUniforms {
    pub count: u32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

/// What the probe found for one texture format.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FormatPrecision {
    pub format: wgpu::TextureFormat,
    /// Fractional bits of the weights, at most [`FilterProbe::RESOLVED_BITS`].
    pub bits: u32,
    /// The rounding that reproduces every sample, if one does (none when the weights are finer than the probe
    /// resolves, or hidden by rounded results).
    pub rounding: Option<WeightRounding>,
    /// The filtered values lie on the 8-bit unorm format's 255 steps.
    pub unorm8_results: bool,
}

impl FormatPrecision {
    /// The filtered value at weight `f` as this model predicts it (the rounding to nearest where it is unresolved).
    #[must_use]
    pub fn predict(&self, f: f32) -> f32 {
        let weights =
            WeightPrecision::Fixed { bits: self.bits, rounding: self.rounding.unwrap_or(WeightRounding::Nearest) };
        let model = FilterPrecision { weights, unorm8_results: self.unorm8_results };
        model.result(self.format, weights.weight(f))
    }
}

/// The device's filtering precision: each format the ray caster filters in hardware here.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct MeasuredFiltering {
    pub formats: Vec<FormatPrecision>,
}

impl MeasuredFiltering {
    /// The fewest weight bits among the formats whose weights the probe resolves: what a test must allow for.
    #[must_use]
    pub fn bits(&self) -> u32 {
        self.formats.iter().filter(|f| !f.unorm8_results).map(|f| f.bits).min().unwrap_or(FilterProbe::RESOLVED_BITS)
    }

    /// The device's own filter, when the probe resolved it: the same bits and rounding for every format whose
    /// weights it sees, coarser than it resolves.
    #[must_use]
    pub fn model(&self) -> Option<FilterPrecision> {
        let mut resolved = self.formats.iter().filter(|f| !f.unorm8_results);
        let first = resolved.next()?;
        let rounding = first.rounding?;
        let same = resolved.all(|f| f.bits == first.bits && f.rounding == Some(rounding));
        (same && first.bits < FilterProbe::RESOLVED_BITS).then_some(FilterPrecision {
            weights: WeightPrecision::Fixed { bits: first.bits, rounding },
            unorm8_results: self.unorm8_results(),
        })
    }

    /// Whether 8-bit unorm volumes come back on their format's steps.
    #[must_use]
    pub fn unorm8_results(&self) -> bool {
        self.formats.iter().any(|f| f.unorm8_results)
    }

    /// One line for logs and summaries, e.g. "R16Unorm 8 bits (nearest), Rgba32Float 8 bits (nearest)".
    #[must_use]
    pub fn describe(&self) -> String {
        let each: Vec<String> = self
            .formats
            .iter()
            .map(|f| {
                let bits = if f.unorm8_results {
                    "results on the format's 255 steps".to_string()
                } else if f.bits >= FilterProbe::RESOLVED_BITS {
                    format!("≥ {} bits", f.bits)
                } else {
                    format!("{} bits", f.bits)
                };
                let unresolved = if f.unorm8_results {
                    "weights hidden"
                } else if f.bits >= FilterProbe::RESOLVED_BITS {
                    "finer than the probe"
                } else {
                    "mixed rounding"
                };
                let rounding = f.rounding.map_or(unresolved, |r| match r {
                    WeightRounding::Down => "rounded down",
                    WeightRounding::Nearest => "rounded to nearest",
                    WeightRounding::Up => "rounded up",
                    WeightRounding::Scattered => "rounded down or up",
                });
                format!("{:?} {bits} ({rounding})", f.format)
            })
            .collect();
        format!("trilinear filter weights: {}", each.join(", "))
    }
}

/// The probe's pipeline.
#[derive(Debug)]
pub struct FilterProbe {
    pipeline: wgpu::ComputePipeline,
    layout: wgpu::BindGroupLayout,
    sampler: wgpu::Sampler,
}

impl FilterProbe {
    /// Weights sampled per format: every multiple of 2⁻¹².
    pub const SAMPLES: u32 = 1 << Self::RESOLVED_BITS;
    /// The finest weight grid the probe resolves.
    pub const RESOLVED_BITS: u32 = 12;
    pub const ENTRY_POINT: &'static str = "cs_filter_probe";

    pub fn new(ctx: &GpuContext) -> Result<Self> {
        let device = &ctx.device;
        let texture = wgpu::BindingType::Texture {
            sample_type: wgpu::TextureSampleType::Float { filterable: true },
            view_dimension: wgpu::TextureViewDimension::D3,
            multisampled: false,
        };
        let layout = compute::layout(
            device,
            "filter probe",
            &[
                binding(SLOT_UNIFORMS, uniform::<ProbeUniforms>()),
                binding(SLOT_TEXTURE, texture),
                binding(SLOT_SAMPLER, wgpu::BindingType::Sampler(wgpu::SamplerBindingType::Filtering)),
                binding(SLOT_OUTPUT, storage(false, None)),
            ],
        );
        let module = SHADER.create_module(device);
        let pipeline = compute::pipeline(device, "filter probe", &module, Some(Self::ENTRY_POINT), &[&layout]);
        let sampler = device.create_sampler(&wgpu::SamplerDescriptor {
            label: Some("filter probe"),
            mag_filter: wgpu::FilterMode::Linear,
            min_filter: wgpu::FilterMode::Linear,
            ..Default::default()
        });
        ctx.check_errors()?;
        Ok(Self { pipeline, layout, sampler })
    }

    /// The formats the ray caster filters in hardware on this device ([`crate::volume`], [`crate::control`]).
    #[must_use]
    pub fn filtered_formats(ctx: &GpuContext) -> Vec<wgpu::TextureFormat> {
        use wgpu::TextureFormat as F;
        let caps = ctx.capabilities;
        let mut formats = Vec::new();
        if caps.norm16 {
            formats.extend([F::R8Unorm, F::R16Unorm]);
        }
        if caps.float32_filterable {
            formats.extend([F::R32Float, F::Rgba32Float]);
        } else {
            formats.push(F::Rgba16Float);
        }
        formats
    }

    /// Measures every format of [`Self::filtered_formats`].
    pub fn measure(&self, ctx: &GpuContext) -> Result<MeasuredFiltering> {
        let formats = Self::filtered_formats(ctx)
            .into_iter()
            .map(|format| self.measure_format(ctx, format))
            .collect::<Result<Vec<_>>>()?;
        Ok(MeasuredFiltering { formats })
    }

    /// The filtered values at weights k/[`Self::SAMPLES`] of a 2×1×1 texture of `format` holding 0 and 1.
    pub fn sample(&self, ctx: &GpuContext, format: wgpu::TextureFormat) -> Result<Vec<f32>> {
        let texels = two_texels(format)
            .ok_or_else(|| GpuError::InvalidInput(format!("the filter probe has no texels for {format:?}")))?;
        let usage = wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST;
        let texture = ctx.texture_3d("filter probe", [2, 1, 1], format, usage);
        ctx.queue.write_texture(
            texture.as_image_copy(),
            &texels,
            wgpu::TexelCopyBufferLayout {
                offset: 0,
                bytes_per_row: Some(texels.len() as u32),
                rows_per_image: Some(1),
            },
            wgpu::Extent3d { width: 2, height: 1, depth_or_array_layers: 1 },
        );
        let view = texture.create_view(&wgpu::TextureViewDescriptor::default());
        let uniforms = ProbeUniforms { count: Self::SAMPLES, _pad0: 0, _pad1: 0, _pad2: 0 };
        let uniform_buffer = ctx.uniform_buffer("filter probe uniforms", &uniforms);
        let bytes = u64::from(Self::SAMPLES) * 4;
        let output =
            ctx.buffer("filter probe output", bytes, wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC);
        let readback =
            ctx.buffer("filter probe readback", bytes, wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST);
        let bind_group = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("filter probe"),
            layout: &self.layout,
            entries: &[
                SLOT_UNIFORMS.entry(uniform_buffer.as_entire_binding()),
                SLOT_TEXTURE.entry(wgpu::BindingResource::TextureView(&view)),
                SLOT_SAMPLER.entry(wgpu::BindingResource::Sampler(&self.sampler)),
                SLOT_OUTPUT.entry(output.as_entire_binding()),
            ],
        });
        let mut encoder =
            ctx.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("filter probe") });
        {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("filter probe"),
                timestamp_writes: None,
            });
            pass.set_pipeline(&self.pipeline);
            pass.set_bind_group(0, &bind_group, &[]);
            pass.dispatch_workgroups(Self::SAMPLES.div_ceil(64), 1, 1);
        }
        encoder.copy_buffer_to_buffer(&output, 0, &readback, 0, bytes);
        ctx.queue.submit([encoder.finish()]);
        ctx.map_read(&readback, bytes, bytemuck::pod_collect_to_vec)
    }

    fn measure_format(&self, ctx: &GpuContext, format: wgpu::TextureFormat) -> Result<FormatPrecision> {
        let values = self.sample(ctx, format)?;
        Ok(analyse(format, &values))
    }
}

/// The bits and rounding that explain `values`, the filtered weights at k/n (module docs).
#[must_use]
pub fn analyse(format: wgpu::TextureFormat, values: &[f32]) -> FormatPrecision {
    let n = values.len() as f32;
    // A value lies on the grid 1/scale when value·scale is an integer, up to the f32 arithmetic of the filter.
    let on_grid = |scale: f32| values.iter().all(|v| (v * scale - (v * scale).round()).abs() <= 1e-3);
    let Some(bits) = (1..FilterProbe::RESOLVED_BITS).find(|&b| on_grid((1u32 << b) as f32)) else {
        let unorm8_results = format == wgpu::TextureFormat::R8Unorm && on_grid(255.0);
        // Every sample's own weight lies on the finest grid the probe resolves (or the format's steps hide it): no
        // rounding can be told.
        return FormatPrecision { format, bits: FilterProbe::RESOLVED_BITS, rounding: None, unorm8_results };
    };
    let rounding = WeightRounding::DEVICE.into_iter().find(|&rounding| {
        let model = WeightPrecision::Fixed { bits, rounding };
        values.iter().enumerate().all(|(k, v)| (model.weight(k as f32 / n) - v).abs() <= 1e-4)
    });
    FormatPrecision { format, bits, rounding, unorm8_results: false }
}

/// Two texels holding 0 and 1 in `format`, as bytes.
fn two_texels(format: wgpu::TextureFormat) -> Option<Vec<u8>> {
    use wgpu::TextureFormat as F;
    let bytes = match format {
        F::R8Unorm => vec![0, 255],
        F::R16Unorm => [0u16, u16::MAX].iter().flat_map(|v| v.to_le_bytes()).collect(),
        F::R32Float => [0f32, 1.0].iter().flat_map(|v| v.to_le_bytes()).collect(),
        F::Rgba32Float => [0f32, 0.0, 0.0, 0.0, 1.0, 1.0, 1.0, 1.0].iter().flat_map(|v| v.to_le_bytes()).collect(),
        F::Rgba16Float => [half::f16::ZERO, half::f16::ZERO, half::f16::ZERO, half::f16::ZERO]
            .iter()
            .chain(&[half::f16::ONE; 4])
            .flat_map(|v| v.to_le_bytes())
            .collect(),
        _ => return None,
    };
    Some(bytes)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_analysis_recovers_the_bits_and_rounding_that_made_the_values() {
        let n = FilterProbe::SAMPLES as usize;
        for bits in [4, 8] {
            for rounding in WeightRounding::DEVICE {
                let model = WeightPrecision::Fixed { bits, rounding };
                let values: Vec<f32> = (0..n).map(|k| model.weight(k as f32 / n as f32)).collect();
                let found = analyse(wgpu::TextureFormat::R16Unorm, &values);
                assert_eq!((found.bits, found.rounding), (bits, Some(rounding)), "{model:?}");
                assert!(
                    values.iter().enumerate().all(|(k, v)| found.predict(k as f32 / n as f32).to_bits() == v.to_bits())
                );
            }
        }
        // Exact weights: as fine as the probe resolves, and at that grid they are exactly the samples' own weights.
        let exact: Vec<f32> = (0..n).map(|k| k as f32 / n as f32).collect();
        let found = analyse(wgpu::TextureFormat::R16Unorm, &exact);
        assert_eq!((found.bits, found.rounding), (FilterProbe::RESOLVED_BITS, None));
        // Weights off every grid (noise): unresolved, and no single rounding explains them.
        let noisy: Vec<f32> = (0..n).map(|k| k as f32 / n as f32 + 1e-3 * ((k * 7919) % 13) as f32 / 13.0).collect();
        let found = analyse(wgpu::TextureFormat::R16Unorm, &noisy);
        assert_eq!((found.bits, found.rounding), (FilterProbe::RESOLVED_BITS, None));
        // An 8-bit unorm texture returning exact weights rounded to its 255 steps.
        let stepped: Vec<f32> = (0..n).map(|k| (k as f32 / n as f32 * 255.0).round() / 255.0).collect();
        let found = analyse(wgpu::TextureFormat::R8Unorm, &stepped);
        assert!(found.unorm8_results && found.rounding.is_none());
        assert!(stepped.iter().enumerate().all(|(k, v)| (found.predict(k as f32 / n as f32) - v).abs() < 1e-6));
        assert!(!analyse(wgpu::TextureFormat::R16Unorm, &stepped).unorm8_results);
    }
}
