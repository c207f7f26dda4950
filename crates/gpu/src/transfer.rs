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
//!
//! **Pre-integration** ([`PreIntegrationTable`]; Engel, Kraus & Ertl 2001, "High-quality pre-integrated volume
//! rendering using hardware-accelerated pixel shading"; Real-Time Volume Graphics §4.5): for one transfer function,
//! opacity scale and ray step, a 256×256 table T(t_f, t_b) of the premultiplied colour and opacity of a ray segment
//! one step long along which the TF coordinate goes linearly from t_f (front sample) to t_b (back sample):
//!
//! α(t_f, t_b) = 1 − exp(−∫₀^Δ τ(t(x)) dx),  C(t_f, t_b) = ∫₀^Δ c(t(x)) τ(t(x)) exp(−∫₀^x τ) dx,
//!
//! with τ the extinction of the opacity-corrected TF: a straight segment at constant t has opacity
//! 1 − (1 − α_TF(t)·scale)^(Δ/ref_step), exactly what per-sample classification gives it. The table is built on the
//! CPU by compositing the segment front to back in one sub-step per transfer-function entry it crosses, each at the
//! midpoint of its entry interval (where the TF is linear) with the opacity correction to the sub-step's length, and
//! the constant segment (t_f = t_b, the diagonal) in one step: so the diagonal is per-sample classification exactly,
//! a segment through zero-opacity entries only is exactly transparent (what empty-space skipping relies on), and
//! the rest converges to the integral as the entries get finer. The ray caster looks it up bilinearly by hand
//! between entries, as it does the TF. Rows are the back entry: texel (f, b) at `texels[b · 256 + f]`.

use rayon::prelude::*;

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
    /// The rows as uploaded, for the pre-integration tables made from them ([`PreIntegrationTable`]).
    pub functions: Vec<TransferFunction>,
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
        let mut functions = rows.to_vec();
        functions
            .resize(n as usize, TransferFunction { name: "transparent".into(), entries: vec![[0; 4]; TF_ENTRIES] });
        Self { texture, view, rows: n, opacity, functions }
    }
}

/// What a [`PreIntegrationTable`] is made from: a transfer function's entries, its opacity scale and the ray step in
/// reference steps (`step_mm / ref_step_mm`). Two frames with equal keys share a table.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct PreIntegrationKey {
    entries: Vec<[u8; 4]>,
    /// f32 bits.
    opacity_scale: u32,
    /// f32 bits.
    step_ratio: u32,
}

impl PreIntegrationKey {
    #[must_use]
    pub fn new(tf: &TransferFunction, opacity_scale: f32, step_ratio: f32) -> Self {
        Self { entries: tf.entries.clone(), opacity_scale: opacity_scale.to_bits(), step_ratio: step_ratio.to_bits() }
    }

    #[must_use]
    pub fn opacity_scale(&self) -> f32 {
        f32::from_bits(self.opacity_scale)
    }

    #[must_use]
    pub fn step_ratio(&self) -> f32 {
        f32::from_bits(self.step_ratio)
    }
}

/// The segment integrals of one transfer function for one step (module docs): premultiplied RGBA of the segment
/// from front entry f to back entry b at `texels[b * TF_ENTRIES + f]`.
#[derive(Clone, Debug, PartialEq)]
pub struct PreIntegrationTable {
    pub texels: Vec<[f32; 4]>,
}

impl PreIntegrationTable {
    /// The table of `tf` with opacities multiplied by `opacity_scale` (then clamped to \[0, 1\], as the ray caster
    /// does), for segments of `step_ratio` reference steps. Rows in parallel on rayon's pool.
    #[must_use]
    pub fn build(tf: &TransferFunction, opacity_scale: f32, step_ratio: f32) -> Self {
        let n = TF_ENTRIES;
        // Straight colour and log2(1 − α) (the opacity correction's exponent base) at t.
        let classify = |t: f32| {
            let s = tf.sample(t);
            let alpha = (s[3] * opacity_scale).clamp(0.0, 1.0);
            ([s[0], s[1], s[2]], (1.0 - alpha).max(1e-7).log2())
        };
        let at_entry: Vec<([f32; 3], f32)> = (0..n).map(|i| classify(i as f32 / (n - 1) as f32)).collect();
        // Midpoints of the intervals between entries i and i + 1.
        let at_mid: Vec<([f32; 3], f32)> = (0..n - 1).map(|i| classify((i as f32 + 0.5) / (n - 1) as f32)).collect();
        let mut texels = vec![[0.0f32; 4]; n * n];
        texels.par_chunks_mut(n).enumerate().for_each(|(back, row)| {
            for (front, texel) in row.iter_mut().enumerate() {
                *texel = if front == back {
                    let (rgb, log_transparency) = at_entry[front];
                    let alpha = 1.0 - (step_ratio * log_transparency).exp2();
                    [rgb[0] * alpha, rgb[1] * alpha, rgb[2] * alpha, alpha]
                } else {
                    let crossed = front.abs_diff(back);
                    let sub_ratio = step_ratio / crossed as f32;
                    let mut acc = [0.0f32; 4];
                    for m in 0..crossed {
                        // The m-th interval from the front: [front + m, front + m + 1] or [front − m − 1, front − m].
                        let interval = if back > front { front + m } else { front - m - 1 };
                        let (rgb, log_transparency) = at_mid[interval];
                        let alpha = 1.0 - (sub_ratio * log_transparency).exp2();
                        let w = (1.0 - acc[3]) * alpha;
                        for c in 0..3 {
                            acc[c] += w * rgb[c];
                        }
                        acc[3] += w;
                    }
                    acc
                };
            }
        });
        Self { texels }
    }

    /// Premultiplied RGBA of the segment from TF coordinate `t_front` to `t_back` (each clamped to \[0, 1\]),
    /// interpolated bilinearly between entries: the shader's `sample_preintegrated`.
    #[must_use]
    pub fn sample(&self, t_front: f32, t_back: f32) -> [f32; 4] {
        let last = TF_ENTRIES - 1;
        let cell = |t: f32| {
            let x = t.clamp(0.0, 1.0) * last as f32;
            let i0 = (x.floor() as usize).min(last);
            (i0, (i0 + 1).min(last), x - i0 as f32)
        };
        let ((f0, f1, wf), (b0, b1, wb)) = (cell(t_front), cell(t_back));
        let at = |f: usize, b: usize| self.texels[b * TF_ENTRIES + f];
        let (p, q, r, s) = (at(f0, b0), at(f1, b0), at(f0, b1), at(f1, b1));
        std::array::from_fn(|c| {
            let lo = p[c] + wf * (q[c] - p[c]);
            let hi = r[c] + wf * (s[c] - r[c]);
            lo + wb * (hi - lo)
        })
    }
}

/// A [`PreIntegrationTable`] as a 256×256 `Rgba32Float` texture (read with `textureLoad`, filtered by hand), with
/// the key it was made from.
#[derive(Debug)]
pub struct GpuPreIntegration {
    pub texture: wgpu::Texture,
    pub view: wgpu::TextureView,
    pub key: PreIntegrationKey,
}

impl GpuPreIntegration {
    /// Builds the table of `key` ([`PreIntegrationTable::build`], ~5.6 M sub-steps: 76 ms on two busy cores in
    /// `benches/quality.rs`) and uploads it.
    #[must_use]
    pub fn build(ctx: &GpuContext, tf: &TransferFunction, key: PreIntegrationKey) -> Self {
        let table = PreIntegrationTable::build(tf, key.opacity_scale(), key.step_ratio());
        let (texture, view) = rgba32f_texture(ctx, "pre-integration table", TF_ENTRIES as u32, &table.texels);
        Self { texture, view, key }
    }

    /// A 1×1 transparent table, bound where a frame does not pre-integrate.
    #[must_use]
    pub(crate) fn placeholder(ctx: &GpuContext) -> wgpu::TextureView {
        rgba32f_texture(ctx, "pre-integration placeholder", 1, &[[0.0; 4]]).1
    }
}

fn rgba32f_texture(
    ctx: &GpuContext,
    label: &str,
    edge: u32,
    texels: &[[f32; 4]],
) -> (wgpu::Texture, wgpu::TextureView) {
    let size = wgpu::Extent3d { width: edge, height: edge, depth_or_array_layers: 1 };
    let texture = ctx.device.create_texture(&wgpu::TextureDescriptor {
        label: Some(label),
        size,
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format: wgpu::TextureFormat::Rgba32Float,
        usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
        view_formats: &[],
    });
    ctx.queue.write_texture(
        texture.as_image_copy(),
        bytemuck::cast_slice(texels),
        wgpu::TexelCopyBufferLayout { offset: 0, bytes_per_row: Some(16 * edge), rows_per_image: Some(edge) },
        size,
    );
    let view = texture.create_view(&wgpu::TextureViewDescriptor::default());
    (texture, view)
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

    /// Premultiplied RGBA of a segment of `step_ratio` reference steps along which t goes linearly from `t_front` to
    /// `t_back`, by brute force: `n` equal sub-steps, each classified at its midpoint through [`TransferFunction::sample`]
    /// and opacity-corrected to its length.
    fn brute_force_segment(tf: &TransferFunction, scale: f32, step_ratio: f32, t_front: f32, t_back: f32) -> [f64; 4] {
        let n = 20_000;
        let mut acc = [0.0f64; 4];
        for m in 0..n {
            let t = t_front + (m as f32 + 0.5) / n as f32 * (t_back - t_front);
            let s = tf.sample(t);
            let alpha = f64::from((s[3] * scale).clamp(0.0, 1.0));
            let alpha = 1.0 - (1.0 - alpha).max(1e-7).powf(f64::from(step_ratio) / f64::from(n));
            let w = (1.0 - acc[3]) * alpha;
            for c in 0..3 {
                acc[c] += w * f64::from(s[c]);
            }
            acc[3] += w;
        }
        acc
    }

    /// The diagonal (a constant segment) is per-sample classification: rgb·α', α' = 1 − (1 − α·scale)^step_ratio.
    #[test]
    fn constant_segments_are_per_sample_classification() {
        let tf = Preset::MrT1.transfer_function();
        for (scale, ratio) in [(1.0f32, 1.0f32), (0.6, 0.5), (2.0, 2.0)] {
            let table = PreIntegrationTable::build(&tf, scale, ratio);
            for i in [0usize, 60, 128, 200, 255] {
                let s = tf.sample(i as f32 / 255.0);
                let alpha = 1.0 - (1.0 - (s[3] * scale).clamp(0.0, 1.0)).max(1e-7).powf(ratio);
                let texel = table.texels[i * TF_ENTRIES + i];
                for c in 0..3 {
                    assert!((texel[c] - s[c] * alpha).abs() < 1e-5, "{scale} {ratio} entry {i}: {texel:?}");
                }
                assert!((texel[3] - alpha).abs() < 1e-5, "{scale} {ratio} entry {i}: {texel:?} vs α {alpha}");
            }
        }
    }

    /// Every entry is within 2/255 of the segment integral by brute force (20 000 sub-steps), and the lookup between
    /// entries within 4/255 of the brute-force integral of the segment it is asked for (the table is linear in
    /// between, the integral is not); opacity does not depend on the direction of the segment.
    #[test]
    fn the_table_is_the_segment_integral() {
        let scale = 1.0;
        for preset in [Preset::MrT1, Preset::CtBone, Preset::CtSoftTissue] {
            let tf = preset.transfer_function();
            for ratio in [1.0f32, 0.5] {
                let table = PreIntegrationTable::build(&tf, scale, ratio);
                let mut worst = 0.0f64;
                for (f, b) in [(0usize, 255usize), (255, 0), (40, 120), (120, 40), (100, 101), (180, 90), (60, 64)] {
                    let exact = brute_force_segment(&tf, scale, ratio, f as f32 / 255.0, b as f32 / 255.0);
                    let texel = table.texels[b * TF_ENTRIES + f];
                    for c in 0..4 {
                        worst = worst.max((f64::from(texel[c]) - exact[c]).abs());
                    }
                    let reverse = table.texels[f * TF_ENTRIES + b];
                    assert!((reverse[3] - texel[3]).abs() < 1e-5, "{preset:?}: α({f}, {b}) ≠ α({b}, {f})");
                }
                assert!(worst < 2.0 / 255.0, "{preset:?} ratio {ratio}: entries off by {worst}");
                let mut worst = 0.0f64;
                for (tf_, tb) in [(0.13f32, 0.77f32), (0.5, 0.5013), (0.91, 0.2), (0.33, 0.331), (0.6, 0.45)] {
                    let exact = brute_force_segment(&tf, scale, ratio, tf_, tb);
                    let got = table.sample(tf_, tb);
                    for c in 0..4 {
                        worst = worst.max((f64::from(got[c]) - exact[c]).abs());
                    }
                }
                assert!(worst < 4.0 / 255.0, "{preset:?} ratio {ratio}: lookups off by {worst}");
            }
        }
    }

    /// A segment whose values cross only zero-opacity entries is exactly transparent (empty-space skipping relies
    /// on it), and a flat TF gives every segment the constant segment's opacity.
    #[test]
    fn transparent_ranges_stay_exactly_transparent() {
        let tf = Preset::MrT1.transfer_function();
        let first_opaque = tf.entries.iter().position(|e| e[3] > 0).expect("an opaque entry");
        let table = PreIntegrationTable::build(&tf, 1.0, 1.0);
        for f in 0..first_opaque {
            for b in 0..first_opaque {
                let texel = table.texels[b * TF_ENTRIES + f];
                assert!(texel.iter().all(|c| c.to_bits() == 0), "({f}, {b}): {texel:?} is not exactly zero");
            }
        }
        // Up to the first opaque entry, the last interval is not transparent.
        assert!(table.texels[first_opaque * TF_ENTRIES][3] > 0.0);
        let flat = TransferFunction { name: "flat".into(), entries: vec![[200, 100, 50, 40]; TF_ENTRIES] };
        let table = PreIntegrationTable::build(&flat, 1.0, 1.0);
        let alpha = 40.0f32 / 255.0;
        for (f, b) in [(0usize, 255usize), (3, 9), (200, 10)] {
            let texel = table.texels[b * TF_ENTRIES + f];
            assert!((texel[3] - alpha).abs() < 1e-5 && (texel[0] - alpha * 200.0 / 255.0).abs() < 1e-5, "{texel:?}");
        }
    }
}
