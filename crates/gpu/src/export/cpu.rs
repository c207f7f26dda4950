//! The CPU path of the export: rayon over the z-slices of each slab, one target row at a time in two steps (the
//! row's source positions, then the samples). The arithmetic is `shaders/export.wgsl`'s, operation for operation:
//! affine maps as ((m₃ + j·m₁) + k·m₂) + i·m₀, lerps as a + f·(b − a), Catmull-Rom sums left to right, the TPS's
//! terms in order (eight voxels at a time, lane by lane, which keeps each voxel's order and lets the compiler use
//! SIMD).

use rayon::prelude::*;

use super::{Acc, report, try_zeroed, with_samples};
use super::{ExportRequest, ExportedVolume, Interpolation, OutputType, Plan, PlanPullBack, Progress, Sample};
use crate::error::Result;
use crate::pullback::TpsLocal;

/// Voxels evaluated together by the TPS kernel.
const LANES: usize = 8;

/// Resamples `request` on the calling thread and rayon's pool, calling `progress` after each slab (see the module
/// docs of [`crate::export`]); `false` from `progress` cancels with [`crate::GpuError::Cancelled`].
pub fn export_cpu(request: &ExportRequest<'_>, progress: &mut dyn FnMut(Progress) -> bool) -> Result<ExportedVolume> {
    let plan = Plan::new(request)?;
    let samples = with_samples!(request.source.samples, |s| run_typed(&plan, s, request.output, progress))?;
    Ok(ExportedVolume { dims: plan.target_dims, lps_from_index: request.target.lps_from_index, samples })
}

/// Slices per slab when the request does not say: several per thread, so that the wait for the slowest slice at the
/// end of each slab (before the progress call) stays small.
fn default_slab_slices() -> usize {
    (4 * rayon::current_num_threads()).max(16)
}

fn run_typed<S: Sample>(
    plan: &Plan,
    source: &[S],
    output: OutputType,
    progress: &mut dyn FnMut(Progress) -> bool,
) -> Result<super::ExportedSamples> {
    match output {
        OutputType::Source => run::<S, S>(plan, source, progress).map(S::wrap),
        OutputType::F32 => run::<S, f32>(plan, source, progress).map(f32::wrap),
    }
}

fn run<S: Sample, O: Sample>(plan: &Plan, source: &[S], progress: &mut dyn FnMut(Progress) -> bool) -> Result<Vec<O>> {
    let mut out = try_zeroed::<O>(plan.output_len)?;
    let [nx, ny, nz] = plan.target_dims;
    let slab = plan.slab_slices.unwrap_or_else(default_slab_slices).clamp(1, nz);
    let outside = O::from_f64(plan.outside_value);
    for (s, chunk) in out.chunks_mut(slab * nx * ny).enumerate() {
        chunk.par_chunks_mut(nx * ny).enumerate().for_each(|(dk, slice)| {
            let k = s * slab + dk;
            let mut scratch = RowScratch::new(nx);
            for (j, row) in slice.chunks_mut(nx).enumerate() {
                scratch.positions(plan, j, k);
                sample_row(plan.interpolation, source, plan.source_dims, &scratch.source_index, row, outside);
            }
        });
        report(progress, ((s + 1) * slab).min(nz), nz)?;
    }
    Ok(out)
}

/// Per-thread buffers of one row.
struct RowScratch {
    source_index: Vec<[f32; 3]>,
    pullback_at: Vec<[f32; 3]>,
    displacement: Vec<[f32; 3]>,
}

/// ((m₃ + j·m₁) + k·m₂): the part of an affine map (columns) that is constant along a row.
#[inline]
fn row_base(m: &[[f32; 4]; 4], j: f32, k: f32) -> [f32; 3] {
    std::array::from_fn(|r| (m[3][r] + j * m[1][r]) + k * m[2][r])
}

#[inline]
fn along_row(base: [f32; 3], m: &[[f32; 4]; 4], i: f32) -> [f32; 3] {
    std::array::from_fn(|r| base[r] + i * m[0][r])
}

impl RowScratch {
    fn new(nx: usize) -> Self {
        Self { source_index: vec![[0.0; 3]; nx], pullback_at: vec![[0.0; 3]; nx], displacement: vec![[0.0; 3]; nx] }
    }

    /// The continuous source index of every voxel of row (j, k) (steps 1 and 2 of the module docs).
    fn positions(&mut self, plan: &Plan, j: usize, k: usize) {
        let (jf, kf) = (j as f32, k as f32);
        let m = &plan.source_index_from_target_index;
        let base = row_base(m, jf, kf);
        for (i, s) in self.source_index.iter_mut().enumerate() {
            *s = along_row(base, m, i as f32);
        }
        if matches!(plan.pullback, PlanPullBack::Identity) {
            return;
        }
        let p = &plan.pullback_from_target_index;
        let base = row_base(p, jf, kf);
        for (i, x) in self.pullback_at.iter_mut().enumerate() {
            *x = along_row(base, p, i as f32);
        }
        match &plan.pullback {
            PlanPullBack::Identity => {}
            PlanPullBack::Control { dims, texels } => {
                let mut cursor = ControlCursor::new(*dims, texels);
                for (d, c) in self.displacement.iter_mut().zip(&self.pullback_at) {
                    *d = cursor.displacement(*c);
                }
            }
            PlanPullBack::Tps(tps) => tps_displacements(tps, &self.pullback_at, &mut self.displacement),
        }
        let l = &plan.source_index_from_lps;
        for (s, d) in self.source_index.iter_mut().zip(&self.displacement) {
            for r in 0..3 {
                s[r] += (l[0][r] * d[0] + l[1][r] * d[1]) + l[2][r] * d[2];
            }
        }
    }
}

#[inline]
fn lerp3(a: [f32; 4], b: [f32; 4], f: f32) -> [f32; 4] {
    std::array::from_fn(|r| a[r] + f * (b[r] - a[r]))
}

/// Trilinear, clamp-to-edge lookups at continuous texel indices (centres at integers): the shader's
/// `control_displacement`. Consecutive voxels of a row mostly fall in the same cell (a 64³ texture under a 256³
/// target: four voxels per cell), so the cell's eight texels are kept until the cell changes.
pub(crate) struct ControlCursor<'a> {
    dims: [usize; 3],
    texels: &'a [[f32; 4]],
    cell: usize,
    corners: [[f32; 4]; 8],
}

impl<'a> ControlCursor<'a> {
    pub(crate) fn new(dims: [usize; 3], texels: &'a [[f32; 4]]) -> Self {
        Self { dims, texels, cell: usize::MAX, corners: [[0.0; 4]; 8] }
    }

    #[inline]
    pub(crate) fn displacement(&mut self, c: [f32; 3]) -> [f32; 3] {
        let dims = self.dims;
        let mut i0 = [0usize; 3];
        let mut f = [0.0f32; 3];
        for a in 0..3 {
            let ca = c[a].max(0.0).min((dims[a] - 1) as f32);
            // ca ≥ 0, so truncation is the floor (one instruction; `f32::floor` is a libm call without SSE4.1).
            i0[a] = ca as usize;
            f[a] = ca - i0[a] as f32;
        }
        let (nx, ny) = (dims[0], dims[1]);
        let cell = i0[0] + nx * (i0[1] + ny * i0[2]);
        if cell != self.cell {
            self.cell = cell;
            let step: [usize; 3] = std::array::from_fn(|a| usize::from(i0[a] + 1 < dims[a]));
            let (dx, dy, dz) = (step[0], step[1] * nx, step[2] * nx * ny);
            let t = self.texels;
            self.corners = [
                t[cell],
                t[cell + dx],
                t[cell + dy],
                t[cell + dx + dy],
                t[cell + dz],
                t[cell + dx + dz],
                t[cell + dy + dz],
                t[cell + dx + dy + dz],
            ];
        }
        let k = &self.corners;
        let x00 = lerp3(k[0], k[1], f[0]);
        let x10 = lerp3(k[2], k[3], f[0]);
        let x01 = lerp3(k[4], k[5], f[0]);
        let x11 = lerp3(k[6], k[7], f[0]);
        let d = lerp3(lerp3(x00, x10, f[1]), lerp3(x01, x11, f[1]), f[2]);
        [d[0], d[1], d[2]]
    }
}

/// [`TpsLocal::displacement`] at every point of `xs` (local mm), `LANES` voxels at a time with each voxel's
/// operations in the same order.
pub(crate) fn tps_displacements(tps: &TpsLocal, xs: &[[f32; 3]], out: &mut [[f32; 3]]) {
    let l = &tps.linear_minus_identity;
    let o = &tps.offset_mm;
    for (chunk, dst) in xs.chunks(LANES).zip(out.chunks_mut(LANES)) {
        let mut x = [[0.0f32; LANES]; 3];
        for (lane, p) in chunk.iter().enumerate() {
            for a in 0..3 {
                x[a][lane] = p[a];
            }
        }
        let mut d = [[0.0f32; LANES]; 3];
        for r in 0..3 {
            for lane in 0..LANES {
                d[r][lane] = ((l[r][0] * x[0][lane] + l[r][1] * x[1][lane]) + l[r][2] * x[2][lane]) + o[r];
            }
        }
        for (p, w) in tps.centres_local.iter().zip(&tps.weights) {
            let mut radius = [0.0f32; LANES];
            for lane in 0..LANES {
                let (dx, dy, dz) = (x[0][lane] - p[0], x[1][lane] - p[1], x[2][lane] - p[2]);
                radius[lane] = ((dx * dx + dy * dy) + dz * dz).sqrt();
            }
            for r in 0..3 {
                for lane in 0..LANES {
                    d[r][lane] += w[r] * radius[lane];
                }
            }
        }
        for (lane, v) in dst.iter_mut().enumerate() {
            *v = [d[0][lane], d[1][lane], d[2][lane]];
        }
    }
}

/// Catmull-Rom weights of the taps at −1, 0, 1, 2 (the shader's `catmull_rom`).
#[inline]
fn catmull_rom(t: f32) -> [f32; 4] {
    [
        t * (-0.5 + t * (1.0 - 0.5 * t)),
        1.0 + t * t * (-2.5 + 1.5 * t),
        t * (0.5 + t * (2.0 - 1.5 * t)),
        t * t * (-0.5 + 0.5 * t),
    ]
}

#[inline]
fn weighted4<A: Acc>(w: [f32; 4], v: [A; 4]) -> A {
    ((A::weight(w[0]) * v[0] + A::weight(w[1]) * v[1]) + A::weight(w[2]) * v[2]) + A::weight(w[3]) * v[3]
}

#[inline]
fn lerp<A: Acc>(a: A, b: A, f: f32) -> A {
    a + A::weight(f) * (b - a)
}

/// ⌊x⌋ for finite |x| < 2³¹, exactly `f32::floor` (which is a libm call on x86-64 without SSE4.1).
#[inline]
fn floor_i32(x: f32) -> i32 {
    let t = x as i32;
    t - i32::from(t as f32 > x)
}

/// Whether `s` lies in the box of voxel edges, −½ ≤ sₐ ≤ nₐ − ½ (false for NaN).
#[inline]
fn inside(s: [f32; 3], n: [f32; 3]) -> bool {
    (0..3).all(|a| s[a] >= -0.5 && s[a] <= n[a] - 0.5)
}

/// Samples `source` at the continuous indices `positions`, writing one output row. Taps are addressed by per-axis
/// offsets (clamped index × stride) summed, so a tap costs two additions.
fn sample_row<S: Sample, O: Sample>(
    interpolation: Interpolation,
    source: &[S],
    dims: [usize; 3],
    positions: &[[f32; 3]],
    out: &mut [O],
    outside: O,
) {
    let n = dims.map(|d| d as f32);
    let last = dims.map(|d| d as isize - 1);
    let stride = [1, dims[0], dims[0] * dims[1]];
    // The offset of index `i` along axis `a`, clamped to the edge.
    let offset = |a: usize, i: isize| i.clamp(0, last[a]) as usize * stride[a];
    let at = |i: usize| source[i].acc();
    let store = |v: S::Acc| O::from_f64(v.to_f64());
    match interpolation {
        Interpolation::Nearest => {
            for (o, s) in out.iter_mut().zip(positions) {
                *o = if inside(*s, n) {
                    let q: [usize; 3] = std::array::from_fn(|a| offset(a, floor_i32(s[a] + 0.5) as isize));
                    store(at(q[0] + q[1] + q[2]))
                } else {
                    outside
                };
            }
        }
        Interpolation::Trilinear => {
            for (o, s) in out.iter_mut().zip(positions) {
                if !inside(*s, n) {
                    *o = outside;
                    continue;
                }
                let s0 = s.map(floor_i32);
                let f: [f32; 3] = std::array::from_fn(|a| s[a] - s0[a] as f32);
                let [x0, y0, z0]: [usize; 3] = std::array::from_fn(|a| offset(a, s0[a] as isize));
                let [x1, y1, z1]: [usize; 3] = std::array::from_fn(|a| offset(a, s0[a] as isize + 1));
                let x00 = lerp(at(x0 + y0 + z0), at(x1 + y0 + z0), f[0]);
                let x10 = lerp(at(x0 + y1 + z0), at(x1 + y1 + z0), f[0]);
                let x01 = lerp(at(x0 + y0 + z1), at(x1 + y0 + z1), f[0]);
                let x11 = lerp(at(x0 + y1 + z1), at(x1 + y1 + z1), f[0]);
                *o = store(lerp(lerp(x00, x10, f[1]), lerp(x01, x11, f[1]), f[2]));
            }
        }
        Interpolation::CatmullRom => {
            for (o, s) in out.iter_mut().zip(positions) {
                if !inside(*s, n) {
                    *o = outside;
                    continue;
                }
                let s0 = s.map(floor_i32);
                let w: [[f32; 4]; 3] = std::array::from_fn(|a| catmull_rom(s[a] - s0[a] as f32));
                let [xs, ys, zs]: [[usize; 4]; 3] =
                    std::array::from_fn(|a| std::array::from_fn(|t| offset(a, s0[a] as isize + t as isize - 1)));
                let along_z: [S::Acc; 4] = std::array::from_fn(|c| {
                    let along_y: [S::Acc; 4] = std::array::from_fn(|b| {
                        let row = ys[b] + zs[c];
                        weighted4(w[0], [at(xs[0] + row), at(xs[1] + row), at(xs[2] + row), at(xs[3] + row)])
                    });
                    weighted4(w[1], along_y)
                });
                *o = store(weighted4(w[2], along_z));
            }
        }
    }
}

#[cfg(test)]
#[allow(clippy::float_cmp, reason = "the laws tested here hold exactly, bit for bit")]
mod tests {
    use super::*;

    #[test]
    fn lane_kernel_is_tps_local_bit_for_bit() {
        let tps = TpsLocal {
            origin_ref: [0.0; 3],
            linear_minus_identity: [[0.01, -0.02, 0.003], [0.0, 0.015, -0.01], [0.02, 0.0, -0.005]],
            offset_mm: [1.5, -0.25, 3.0],
            centres_local: vec![[10.0, -20.0, 5.0], [-30.0, 12.5, 40.0], [0.0, 0.0, -7.0]],
            weights: vec![[0.01, -0.03, 0.02], [-0.02, 0.01, 0.0], [0.01, 0.02, -0.02]],
        };
        let xs: Vec<[f32; 3]> = (0..13).map(|i| [i as f32 * 3.7 - 20.0, 11.0 - i as f32, 0.5 * i as f32]).collect();
        let mut out = vec![[0.0; 3]; xs.len()];
        tps_displacements(&tps, &xs, &mut out);
        for (x, d) in xs.iter().zip(&out) {
            assert_eq!(*d, tps.displacement(*x));
        }
    }

    #[test]
    fn constant_control_textures_give_exactly_their_constant() {
        let constant = [0.1f32, -3.7, 1e-3, 0.0];
        let texels = vec![constant; 5 * 4 * 3];
        let mut cursor = ControlCursor::new([5, 4, 3], &texels);
        for i in 0..1000u16 {
            let t = f32::from(i);
            let c = [(t * 0.618_034).fract() * 6.0 - 0.5, (t * 0.414_214).fract() * 5.0 - 0.5, t * 0.003];
            assert_eq!(cursor.displacement(c), [constant[0], constant[1], constant[2]], "at {c:?}");
        }
    }

    #[test]
    fn catmull_rom_weights_interpolate_and_sum_to_one() {
        assert_eq!(catmull_rom(0.0), [0.0, 1.0, 0.0, 0.0]);
        for t in [0.1f32, 0.25, 0.5, 0.9] {
            let w = catmull_rom(t);
            assert!((w.iter().sum::<f32>() - 1.0).abs() < 1e-6, "{t}: {w:?}");
            // Reproduces linear functions: Σ wᵢ (i − 1) = t.
            assert!((-w[0] + w[2] + 2.0 * w[3] - t).abs() < 1e-6, "{t}: {w:?}");
        }
    }
}
