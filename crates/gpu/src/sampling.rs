//! Texture sampling as the GPU's filtered lookups do it, in f32 on the CPU: shared by the preparation code
//! ([`crate::control::PreparedControl::displacement`]) and the CPU reference of the passes ([`crate::cpu_reference`]).
//!
//! **Filtering precision.** A shader that filters by hand (`textureLoad` and `mix`) computes its trilinear weights in
//! f32. A device's hardware filter (`textureSampleLevel` through a linear sampler) may round each weight to a multiple
//! of 2⁻ᵇ first, b being Vulkan's `subTexelPrecisionBits`: 8 on NVIDIA, AMD and Intel GPUs, at least 4 on any
//! conformant device, and the direction of the rounding is the device's own ([`WeightPrecision`]). Some filters also
//! return an 8-bit unorm texture's filtered value on the format's own 255 steps (lavapipe does). [`FilterPrecision`]
//! is that model of a device; the CPU reference applies it to the lookups the GPU filters in hardware, so that a test
//! can state how far a conformant device may be from the exact reference ([`FilterPrecision::family`]).
//! [`crate::filter_probe`] measures a device.

use glam::{Vec3, Vec4};

/// How a hardware filter rounds its trilinear weights (module docs).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum WeightPrecision {
    /// Weights in f32: the shaders' manual filtering, and devices whose filter is finer than it matters.
    #[default]
    Exact,
    /// Weights rounded to a multiple of 2^-`bits` in the direction `rounding`.
    Fixed { bits: u32, rounding: WeightRounding },
}

/// The direction a fixed-point filter weight is rounded.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum WeightRounding {
    Down,
    Nearest,
    Up,
    /// Down or up, by a hash of the weight: a direction that changes from lookup to lookup, as rounding to nearest
    /// does, with a full step's error. Rounding every weight the same way makes the errors of a ray's samples
    /// partly cancel (a rising and a falling edge move apart); a device whose direction varies does not.
    Scattered,
}

impl WeightRounding {
    /// The directions a device may round in ([`Self::Scattered`] is a model, not a device's rule).
    pub const DEVICE: [Self; 3] = [Self::Down, Self::Nearest, Self::Up];
}

impl WeightPrecision {
    /// The weight `f` ∈ \[0, 1) as the filter uses it.
    #[must_use]
    pub fn weight(self, f: f32) -> f32 {
        match self {
            Self::Exact => f,
            Self::Fixed { bits, rounding } => {
                let scale = (1u32 << bits.min(23)) as f32;
                let steps = match rounding {
                    WeightRounding::Down => (f * scale).floor(),
                    WeightRounding::Nearest => (f * scale).round(),
                    WeightRounding::Up => (f * scale).ceil(),
                    WeightRounding::Scattered => {
                        let h = f.to_bits().wrapping_mul(0x9E37_79B9);
                        if h >> 31 == 0 { (f * scale).floor() } else { (f * scale).ceil() }
                    }
                };
                steps / scale
            }
        }
    }
}

/// A device's hardware filter as the CPU reference models it (module docs).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FilterPrecision {
    pub weights: WeightPrecision,
    /// A filtered 8-bit unorm texel (`R8Unorm`: u8 volumes) comes back on the format's 255 steps
    /// ([`Self::result`]).
    pub unorm8_results: bool,
}

impl FilterPrecision {
    /// Exact f32 weights and results: what the shaders' manual filtering computes.
    pub const EXACT: Self = Self { weights: WeightPrecision::Exact, unorm8_results: false };

    /// The models that span every device whose filter weights have `bits` fractional bits, whatever the direction
    /// of their rounding, with 8-bit unorm results as `unorm8_results` says: every weight rounded down, every one
    /// up (the largest error of one lookup, either sign), and each down or up as it falls ([`WeightRounding::Scattered`],
    /// the errors of a ray's lookups adding up instead of cancelling). Rounding to nearest errs by half a step, within
    /// these. The images of the family span how far such a device may be from the exact reference.
    #[must_use]
    pub fn family(bits: u32, unorm8_results: bool) -> [Self; 3] {
        [WeightRounding::Down, WeightRounding::Up, WeightRounding::Scattered]
            .map(|rounding| Self { weights: WeightPrecision::Fixed { bits, rounding }, unorm8_results })
    }

    /// A filtered normalised value of a texture of `format` as the device returns it: an 8-bit unorm result on the
    /// format's steps, rounded in the direction of the weights (to nearest with exact weights), as fixed-point filter
    /// arithmetic does.
    #[must_use]
    pub fn result(self, format: wgpu::TextureFormat, value: f32) -> f32 {
        if !(self.unorm8_results && format == wgpu::TextureFormat::R8Unorm) {
            return value;
        }
        let steps = value * 255.0;
        let steps = match self.weights {
            WeightPrecision::Fixed { rounding: WeightRounding::Down, .. } => steps.floor(),
            WeightPrecision::Fixed { rounding: WeightRounding::Up, .. } => steps.ceil(),
            _ => steps.round(),
        };
        steps / 255.0
    }
}

/// Trilinear interpolation at `p_tex` ∈ \[0, 1\]³ of a `dims` grid with texel centres at (i + ½)/n and clamp-to-edge
/// addressing; `texel(i)` returns the texel at linear index i (x fastest). Exact f32 weights, as a shader filtering by
/// hand computes them.
pub fn trilinear(dims: [u32; 3], p_tex: Vec3, texel: impl Fn(usize) -> Vec4) -> Vec4 {
    trilinear_with(WeightPrecision::Exact, dims, p_tex, texel)
}

/// [`trilinear`] with the weights of a hardware filter of precision `precision`.
pub fn trilinear_with(precision: WeightPrecision, dims: [u32; 3], p_tex: Vec3, texel: impl Fn(usize) -> Vec4) -> Vec4 {
    let n = Vec3::new(dims[0] as f32, dims[1] as f32, dims[2] as f32);
    let c = (p_tex * n - Vec3::splat(0.5)).clamp(Vec3::ZERO, n - Vec3::ONE);
    let i0 = c.floor();
    let f = c - i0;
    let f = Vec3::new(precision.weight(f.x), precision.weight(f.y), precision.weight(f.z));
    let i0 = [i0.x as usize, i0.y as usize, i0.z as usize];
    let i1 = [0, 1, 2].map(|a| (i0[a] + 1).min(dims[a] as usize - 1));
    let (nx, ny) = (dims[0] as usize, dims[1] as usize);
    let at = |x: usize, y: usize, z: usize| texel(x + nx * (y + ny * z));
    let x00 = at(i0[0], i0[1], i0[2]).lerp(at(i1[0], i0[1], i0[2]), f.x);
    let x10 = at(i0[0], i1[1], i0[2]).lerp(at(i1[0], i1[1], i0[2]), f.x);
    let x01 = at(i0[0], i0[1], i1[2]).lerp(at(i1[0], i0[1], i1[2]), f.x);
    let x11 = at(i0[0], i1[1], i1[2]).lerp(at(i1[0], i1[1], i1[2]), f.x);
    x00.lerp(x10, f.y).lerp(x01.lerp(x11, f.y), f.z)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn texel_centres_are_reproduced_and_edges_clamp() {
        // A 2×1×1 grid of values 1 and 3: centres at tex x = ¼ and ¾, linear between, constant beyond.
        let values = [Vec4::splat(1.0), Vec4::splat(3.0)];
        let at = |x: f32| trilinear([2, 1, 1], Vec3::new(x, 0.5, 0.5), |i| values[i]).x;
        assert!((at(0.25) - 1.0).abs() < 1e-6);
        assert!((at(0.75) - 3.0).abs() < 1e-6);
        assert!((at(0.5) - 2.0).abs() < 1e-6);
        assert!((at(0.0) - 1.0).abs() < 1e-6 && (at(1.0) - 3.0).abs() < 1e-6);
    }

    #[test]
    fn fixed_point_weights_round_as_named_and_exact_ones_do_not() {
        let f = 0.3f32;
        assert_eq!(WeightPrecision::Exact.weight(f).to_bits(), f.to_bits());
        let fixed = |bits, rounding| WeightPrecision::Fixed { bits, rounding }.weight(f);
        // 0.3 · 16 = 4.8: 4/16 down, 5/16 to nearest and up.
        let [down, nearest, up] = WeightRounding::DEVICE.map(|r| fixed(4, r));
        assert_eq!((down, nearest, up), (0.25, 0.3125, 0.3125));
        let [down, nearest, up] = WeightRounding::DEVICE.map(|r| fixed(8, r));
        assert_eq!((down, nearest, up), (76.0 / 256.0, 77.0 / 256.0, 77.0 / 256.0));
        // Scattered: each weight down or up, both directions taken over many weights.
        let scattered: Vec<f32> = (0..64).map(|k| 0.01 + k as f32 / 67.0).collect();
        let rounded = |f: f32| WeightPrecision::Fixed { bits: 4, rounding: WeightRounding::Scattered }.weight(f);
        let on_a_side = |f: f32| [(f * 16.0).floor(), (f * 16.0).ceil()].map(|s| (s / 16.0).to_bits());
        assert!(scattered.iter().all(|&f| on_a_side(f).contains(&rounded(f).to_bits())));
        assert!(scattered.iter().any(|&f| rounded(f) < f) && scattered.iter().any(|&f| rounded(f) > f));
        // 8-bit unorm results on their 255 steps, other formats as they are.
        let rounded = FilterPrecision { unorm8_results: true, ..FilterPrecision::EXACT };
        assert_eq!(rounded.result(wgpu::TextureFormat::R8Unorm, 0.3).to_bits(), (77.0f32 / 255.0).to_bits());
        assert_eq!(rounded.result(wgpu::TextureFormat::R16Unorm, 0.3).to_bits(), 0.3f32.to_bits());
        // Between texel centres 1 and 3 at weight 0.3: 1.6 exactly, 1.5 with 4-bit weights rounded down.
        let values = [Vec4::splat(1.0), Vec4::splat(3.0)];
        let p = Vec3::new(f32::midpoint(0.5, f), 0.5, 0.5);
        let down = WeightPrecision::Fixed { bits: 4, rounding: WeightRounding::Down };
        let quantised = trilinear_with(down, [2, 1, 1], p, |i| values[i]).x;
        assert!((trilinear([2, 1, 1], p, |i| values[i]).x - 1.6).abs() < 1e-6);
        assert!((quantised - 1.5).abs() < 1e-6, "{quantised}");
    }
}
