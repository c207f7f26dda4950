//! 1-D transfer functions (value → colour and opacity) and their window/level mapping.
//!
//! A [`TransferFunction`] has 256 RGBA8 entries over the TF coordinate t ∈ \[0, 1\]; entry i sits at t = i/255. A
//! [`Window`] maps a volume value to t: `t = clamp((value − (level − width/2)) / width, 0, 1)`. Several transfer
//! functions are stacked as rows of one 256×N `Rgba8Unorm` 2-D texture ([`GpuTransferFunctions`]; 2-D rather than
//! 1-D, stack.md gotcha 7). The shader interpolates linearly between entries ⌊255·t⌋ and the next **by hand** (two
//! `textureLoad`): lavapipe's sampler uses 8-bit filtering weights for this format, and the resulting bias in small
//! opacities grows over ~100 composited samples (measured: up to 8/255 against the f32 reference).
//!
//! Entries hold **straight (non-premultiplied)** colour and opacity. The ray caster interpolates straight RGBA,
//! applies the opacity correction to α, and premultiplies afterwards; the CPU reference
//! ([`TransferFunction::sample`]) does the same.

use crate::device::GpuContext;

/// A window/level: the value range [level − width/2, level + width/2] spans the transfer function.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Window {
    pub level: f32,
    pub width: f32,
}

impl Window {
    /// The window spanning `[low, high]`.
    #[must_use]
    pub fn from_range(low: f32, high: f32) -> Self {
        Self { level: 0.5 * (low + high), width: (high - low).max(f32::MIN_POSITIVE) }
    }
    #[must_use]
    pub fn low(&self) -> f32 {
        self.level - 0.5 * self.width
    }
    /// The TF coordinate of `value` (the shader's formula).
    #[must_use]
    pub fn tf_coord(&self, value: f32) -> f32 {
        ((value - self.low()) / self.width).clamp(0.0, 1.0)
    }
}

/// 256 straight-alpha RGBA8 entries over t ∈ \[0, 1\].
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct TransferFunction {
    pub name: String,
    pub entries: Vec<[u8; 4]>,
}

/// Entries per transfer function (the texture width).
pub const TF_ENTRIES: usize = 256;

impl TransferFunction {
    /// Piecewise-linear through `points` = (t, straight RGBA in \[0, 1\]), sorted by t; constant beyond the ends.
    #[must_use]
    pub fn from_points(name: &str, points: &[(f32, [f32; 4])]) -> Self {
        let entries = (0..TF_ENTRIES)
            .map(|i| {
                let t = i as f32 / (TF_ENTRIES - 1) as f32;
                let c = match points.iter().position(|(pt, _)| *pt >= t) {
                    None => points.last().map_or([0.0; 4], |p| p.1),
                    Some(0) => points[0].1,
                    Some(k) => {
                        let ((t0, c0), (t1, c1)) = (points[k - 1], points[k]);
                        let f = if t1 > t0 { (t - t0) / (t1 - t0) } else { 1.0 };
                        std::array::from_fn(|ch| c0[ch] + f * (c1[ch] - c0[ch]))
                    }
                };
                c.map(|x| (x.clamp(0.0, 1.0) * 255.0).round() as u8)
            })
            .collect();
        Self { name: name.to_string(), entries }
    }

    /// Straight RGBA at t, interpolated linearly between entries (the shader's `sample_tf`).
    #[must_use]
    pub fn sample(&self, t: f32) -> [f32; 4] {
        let x = t.clamp(0.0, 1.0) * 255.0;
        let i0 = (x.floor() as usize).min(TF_ENTRIES - 1);
        let i1 = (i0 + 1).min(TF_ENTRIES - 1);
        let f = x - i0 as f32;
        let (a, b) = (self.entries[i0], self.entries[i1]);
        std::array::from_fn(|c| {
            let (a, b) = (f32::from(a[c]) / 255.0, f32::from(b[c]) / 255.0);
            a + f * (b - a)
        })
    }
}

/// Built-in transfer functions, each with a default window where the modality fixes one.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Preset {
    /// CT: soft tissue transparent, bone from ~200 HU ivory and opaque.
    CtBone,
    /// CT: skin and soft tissue semi-transparent, bone white.
    CtSoftTissue,
    /// MR T1: dark fluid transparent, grey/white matter warm and semi-transparent.
    MrT1,
    /// Grey ramp, opacity rising with value.
    GreyRamp,
}

impl Preset {
    pub const ALL: [Self; 4] = [Self::CtBone, Self::CtSoftTissue, Self::MrT1, Self::GreyRamp];

    #[must_use]
    pub fn transfer_function(self) -> TransferFunction {
        match self {
            Self::CtBone => TransferFunction::from_points(
                "ct-bone",
                &[
                    (0.0, [0.0, 0.0, 0.0, 0.0]),
                    (0.3, [0.55, 0.25, 0.15, 0.0]),
                    (0.4, [0.9, 0.75, 0.55, 0.25]),
                    (0.6, [1.0, 0.95, 0.85, 0.7]),
                    (1.0, [1.0, 1.0, 1.0, 0.9]),
                ],
            ),
            Self::CtSoftTissue => TransferFunction::from_points(
                "ct-soft-tissue",
                &[
                    (0.0, [0.0, 0.0, 0.0, 0.0]),
                    (0.35, [0.6, 0.3, 0.2, 0.0]),
                    (0.45, [0.85, 0.55, 0.45, 0.04]),
                    (0.7, [0.95, 0.8, 0.7, 0.08]),
                    (0.85, [1.0, 1.0, 0.95, 0.6]),
                    (1.0, [1.0, 1.0, 1.0, 0.8]),
                ],
            ),
            Self::MrT1 => TransferFunction::from_points(
                "mr-t1",
                &[
                    (0.0, [0.0, 0.0, 0.0, 0.0]),
                    (0.2, [0.3, 0.2, 0.4, 0.0]),
                    (0.45, [0.75, 0.55, 0.45, 0.06]),
                    (0.75, [0.95, 0.85, 0.7, 0.2]),
                    (1.0, [1.0, 1.0, 0.95, 0.5]),
                ],
            ),
            Self::GreyRamp => {
                TransferFunction::from_points("grey-ramp", &[(0.0, [0.0, 0.0, 0.0, 0.0]), (1.0, [1.0, 1.0, 1.0, 1.0])])
            }
        }
    }

    /// The window for CT presets (HU); `None` for MR and the ramp, whose windows depend on the data
    /// (use [`Window::from_range`] over the volume's range or percentiles).
    #[must_use]
    pub fn default_window(self) -> Option<Window> {
        match self {
            Self::CtBone => Some(Window::from_range(-300.0, 1700.0)),
            Self::CtSoftTissue => Some(Window::from_range(-1000.0, 1000.0)),
            Self::MrT1 | Self::GreyRamp => None,
        }
    }
}

/// The transfer functions of a frame, as one 256×N `Rgba8Unorm` texture (row r is `rows[r]`).
#[derive(Debug)]
pub struct GpuTransferFunctions {
    pub texture: wgpu::Texture,
    pub view: wgpu::TextureView,
    pub rows: u32,
    /// Which entries of each row have non-zero opacity, for empty-space skipping ([`crate::empty_space`]).
    pub opacity: Vec<OpacityTable>,
}

impl GpuTransferFunctions {
    #[must_use]
    pub fn upload(ctx: &GpuContext, rows: &[TransferFunction]) -> Self {
        let n = rows.len().max(1) as u32;
        let size = wgpu::Extent3d { width: TF_ENTRIES as u32, height: n, depth_or_array_layers: 1 };
        let texture = ctx.device.create_texture(&wgpu::TextureDescriptor {
            label: Some("transfer functions"),
            size,
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: wgpu::TextureFormat::Rgba8Unorm,
            usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
            view_formats: &[],
        });
        let mut bytes: Vec<u8> = rows.iter().flat_map(|tf| tf.entries.iter().flatten().copied()).collect();
        bytes.resize(TF_ENTRIES * 4 * n as usize, 0);
        ctx.queue.write_texture(
            texture.as_image_copy(),
            &bytes,
            wgpu::TexelCopyBufferLayout {
                offset: 0,
                bytes_per_row: Some(TF_ENTRIES as u32 * 4),
                rows_per_image: Some(n),
            },
            size,
        );
        let view = texture.create_view(&wgpu::TextureViewDescriptor::default());
        let mut opacity: Vec<OpacityTable> = rows.iter().map(|tf| OpacityTable::new(&tf.entries)).collect();
        opacity.resize(n as usize, OpacityTable::new(&[[0; 4]; TF_ENTRIES]));
        Self { texture, view, rows: n, opacity }
    }
}

/// Which transfer-function entries have non-zero opacity, with prefix counts for O(1) range queries.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct OpacityTable {
    /// `prefix[i]`: the number of entries below i with non-zero opacity (`TF_ENTRIES + 1` counts).
    prefix: Vec<u16>,
}

impl OpacityTable {
    /// The table of one transfer function's entries (straight RGBA8).
    #[must_use]
    pub fn new(entries: &[[u8; 4]]) -> Self {
        let mut prefix = Vec::with_capacity(entries.len() + 1);
        let mut n = 0u16;
        prefix.push(0);
        for e in entries {
            n += u16::from(e[3] > 0);
            prefix.push(n);
        }
        Self { prefix }
    }

    /// Whether any entry in `lo ..= hi` (clamped to the table) has non-zero opacity.
    #[must_use]
    pub fn any_opaque(&self, lo: i64, hi: i64) -> bool {
        let last = self.prefix.len() as i64 - 2;
        if last < 0 || hi < lo || hi < 0 || lo > last {
            return false;
        }
        let (lo, hi) = (lo.clamp(0, last) as usize, hi.clamp(0, last) as usize);
        hi >= lo && self.prefix[hi + 1] > self.prefix[lo]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn window_maps_its_ends_to_0_and_1() {
        let w = Window::from_range(-1000.0, 1000.0);
        assert!((w.tf_coord(-1000.0)).abs() < 1e-6 && (w.tf_coord(1000.0) - 1.0).abs() < 1e-6);
        assert!((w.tf_coord(0.0) - 0.5).abs() < 1e-6 && (w.tf_coord(5000.0) - 1.0).abs() < 1e-9);
    }

    #[test]
    fn sampling_hits_entries_and_interpolates_between() {
        let tf = Preset::GreyRamp.transfer_function();
        assert_eq!(tf.entries.len(), TF_ENTRIES);
        for i in [0usize, 17, 128, 255] {
            let s = tf.sample(i as f32 / 255.0);
            assert!((s[0] - f32::from(tf.entries[i][0]) / 255.0).abs() < 1e-5, "{i}");
        }
        let mid = tf.sample(0.5 / 255.0);
        assert!((mid[3] - 0.5 * f32::from(tf.entries[1][3]) / 255.0).abs() < 1e-5);
        for p in Preset::ALL {
            assert_eq!(p.transfer_function().entries[0][3], 0, "{p:?}: zero opacity at the bottom");
        }
    }
}
