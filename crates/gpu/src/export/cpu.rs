//! The CPU path of the export: rayon over the z-slices of each slab, one target row at a time in two steps (the
//! row's source positions, then the samples). The arithmetic is `shaders/export.wgsl`'s, operation for operation:
//! affine maps as ((m₃ + j·m₁) + k·m₂) + i·m₀, lerps as a + f·(b − a), Catmull-Rom sums left to right, the TPS's
//! terms in order (a block of voxels at a time, lane by lane, which keeps each voxel's order and lets the compiler
//! use SIMD; see [`tps_row`]).
//!
//! One exception: a control texture's displacement along a row that runs along the texture's x axis (the usual
//! case: the texture laid over the target grid) is interpolated in y and z once per texel column of the row, then
//! in x per voxel ([`control_along_x`]), instead of the shader's x, then y, then z at every voxel. Trilinear
//! interpolation is separable, so the value is the same up to f32 rounding: a few roundings of the displacement
//! (at most 8 ε·max |texel|, tested against the per-voxel [`ControlCursor`]), under 2·10⁻⁵ voxel in the source
//! position for displacements up to 10 mm on a source grid of 0.5 mm or coarser.
//!
//! The output is not zeroed first: each row is built in a per-thread buffer and copied into the output's
//! uninitialised capacity, so its pages are first touched by the thread that fills them (no single-threaded memset
//! and page-fault storm before the parallel work).

#![allow(
    clippy::inline_always,
    reason = "the row code must be inlined into `fill_row_avx2` to be compiled with its target features"
)]

use rayon::prelude::*;

use super::plan::{Plan, PlanPullBack, report};
use super::request::{ExportRequest, ExportedSamples, ExportedVolume, Interpolation, OutputType, Progress};
use super::sample::{Acc, Sample, try_reserved, with_samples};
use crate::error::Result;
use crate::pullback::TpsLocal;

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
) -> Result<ExportedSamples> {
    match output {
        OutputType::Source => run::<S, S>(plan, source, progress).map(S::wrap),
        OutputType::F32 => run::<S, f32>(plan, source, progress).map(f32::wrap),
    }
}

fn run<S: Sample, O: Sample>(plan: &Plan, source: &[S], progress: &mut dyn FnMut(Progress) -> bool) -> Result<Vec<O>> {
    let mut out = try_reserved::<O>(plan.output_len)?;
    let [nx, ny, nz] = plan.target_dims;
    let slab = plan.slab_slices.unwrap_or_else(default_slab_slices).clamp(1, nz);
    let outside = O::from_f64(plan.outside_value);
    let isa = Isa::detect();
    let spare = &mut out.spare_capacity_mut()[..plan.output_len];
    for (s, chunk) in spare.chunks_mut(slab * nx * ny).enumerate() {
        chunk.par_chunks_mut(nx * ny).enumerate().for_each(|(dk, slice)| {
            let k = s * slab + dk;
            let mut scratch = RowScratch::new(nx, plan);
            let mut row = vec![outside; nx];
            for (j, dst) in slice.chunks_mut(nx).enumerate() {
                fill_row(isa, plan, source, &mut scratch, &mut row, [j, k], outside);
                dst.write_copy_of_slice(&row);
            }
        });
        report(progress, ((s + 1) * slab).min(nz), nz)?;
    }
    #[allow(unsafe_code, reason = "the output is filled in place, without zeroing it first (module docs)")]
    // SAFETY: `spare` is the first `output_len` elements of the capacity, `try_reserved` reserved at least that many,
    // and the loop above wrote every one of them: the slabs' chunks tile `spare`, each chunk's slices tile the chunk,
    // and each slice's rows tile the slice (output_len = nx·ny·nz). A cancelled export returns before this with
    // `out` still empty.
    unsafe {
        out.set_len(plan.output_len);
    }
    Ok(out)
}

/// The instruction set the row loops are built for, detected once per export.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Isa {
    /// The target's baseline (SSE2 on x86-64).
    Portable,
    /// x86-64 with AVX2 and FMA: the row loops in an AVX2 build, and the TPS kernel of [`simd`].
    #[cfg(target_arch = "x86_64")]
    Avx2Fma,
}

impl Isa {
    pub(crate) fn detect() -> Self {
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
                return Self::Avx2Fma;
            }
        }
        Self::Portable
    }
}

/// Writes target row (j, k): its source positions, then its samples. The work is SIMD-friendly loops over the row,
/// so with [`Isa::Avx2Fma`] it runs in an AVX2 build of the same code.
fn fill_row<S: Sample, O: Sample>(
    isa: Isa,
    plan: &Plan,
    source: &[S],
    scratch: &mut RowScratch,
    row: &mut [O],
    jk: [usize; 2],
    outside: O,
) {
    match isa {
        Isa::Portable => fill_row_portable(isa, plan, source, scratch, row, jk, outside),
        #[cfg(target_arch = "x86_64")]
        Isa::Avx2Fma => {
            #[allow(unsafe_code, reason = "runtime dispatch to the AVX2 build of the same safe code")]
            // SAFETY: the only requirement of a `target_feature` function is that the CPU has the features, and
            // `Isa::detect` found them.
            unsafe {
                fill_row_avx2(isa, plan, source, scratch, row, jk, outside);
            }
        }
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn fill_row_avx2<S: Sample, O: Sample>(
    isa: Isa,
    plan: &Plan,
    source: &[S],
    scratch: &mut RowScratch,
    row: &mut [O],
    jk: [usize; 2],
    outside: O,
) {
    fill_row_portable(isa, plan, source, scratch, row, jk, outside);
}

#[inline(always)]
fn fill_row_portable<S: Sample, O: Sample>(
    isa: Isa,
    plan: &Plan,
    source: &[S],
    scratch: &mut RowScratch,
    row: &mut [O],
    [j, k]: [usize; 2],
    outside: O,
) {
    scratch.positions(isa, plan, j, k);
    let [sx, sy, sz] = &scratch.source_index;
    sample_row(plan.interpolation, source, plan.source_dims, [sx, sy, sz], row, outside);
}

/// Per-thread buffers of one row, as structure of arrays (one `Vec` per axis) so that the row loops vectorise.
struct RowScratch {
    /// Continuous source index of each voxel.
    source_index: [Vec<f32>; 3],
    /// Where the pull-back is evaluated: each voxel in the pull-back's local mm.
    pullback_at: [Vec<f32>; 3],
    /// The pull-back's displacement at each voxel, local mm.
    displacement: [Vec<f32>; 3],
    /// A control texture's columns interpolated at the row's y and z ([`control_along_x`]).
    columns: ControlColumns,
}

/// ((m₃ + j·m₁) + k·m₂): the part of an affine map (columns) that is constant along a row.
#[inline(always)]
fn row_base(m: &[[f32; 4]; 4], j: f32, k: f32) -> [f32; 3] {
    std::array::from_fn(|r| (m[3][r] + j * m[1][r]) + k * m[2][r])
}

/// base + i·m₀ for i = 0, 1, …, per axis: the row's positions under the affine map m.
#[inline(always)]
fn along_row(base: [f32; 3], m: &[[f32; 4]; 4], out: &mut [Vec<f32>; 3]) {
    for (r, o) in out.iter_mut().enumerate() {
        for (i, v) in o.iter_mut().enumerate() {
            *v = base[r] + i as f32 * m[0][r];
        }
    }
}

impl RowScratch {
    fn new(nx: usize, plan: &Plan) -> Self {
        let row = || std::array::from_fn(|_| vec![0.0; nx]);
        let texels_x = match &plan.pullback {
            PlanPullBack::Control { dims, .. } => dims[0],
            _ => 0,
        };
        let columns = ControlColumns::new(texels_x);
        Self { source_index: row(), pullback_at: row(), displacement: row(), columns }
    }

    /// The continuous source index of every voxel of row (j, k) (steps 1 and 2 of the module docs).
    #[inline(always)]
    fn positions(&mut self, isa: Isa, plan: &Plan, j: usize, k: usize) {
        let (jf, kf) = (j as f32, k as f32);
        let m = &plan.source_index_from_target_index;
        along_row(row_base(m, jf, kf), m, &mut self.source_index);
        if matches!(plan.pullback, PlanPullBack::Identity) {
            return;
        }
        let p = &plan.pullback_from_target_index;
        along_row(row_base(p, jf, kf), p, &mut self.pullback_at);
        let [x, y, z] = &self.pullback_at;
        match &plan.pullback {
            PlanPullBack::Identity => {}
            PlanPullBack::Control { dims, texels } if p[0][1] == 0.0 && p[0][2] == 0.0 => {
                // The row runs along the texture's x: every voxel's texel y and z are exactly base + i·0.
                control_along_x(*dims, texels, x, [y[0], z[0]], &mut self.columns, &mut self.displacement);
            }
            PlanPullBack::Control { dims, texels } => {
                let mut cursor = ControlCursor::new(*dims, texels);
                let [d0, d1, d2] = &mut self.displacement;
                let d = d0.iter_mut().zip(d1.iter_mut()).zip(d2.iter_mut());
                for (((d0, d1), d2), ((x, y), z)) in d.zip(x.iter().zip(y).zip(z)) {
                    [*d0, *d1, *d2] = cursor.displacement([*x, *y, *z]);
                }
            }
            PlanPullBack::Tps(tps) => {
                // The row runs along local x only when the map's first column has no y and z part; then every
                // voxel's y and z are exactly base + i·0.
                let along_x = p[0][1] == 0.0 && p[0][2] == 0.0;
                tps_row(tps, [x, y, z], along_x, isa, &mut self.displacement);
            }
        }
        let l = &plan.source_index_from_lps;
        let [d0, d1, d2] = &self.displacement;
        for (r, s) in self.source_index.iter_mut().enumerate() {
            for (s, ((d0, d1), d2)) in s.iter_mut().zip(d0.iter().zip(d1).zip(d2)) {
                *s += (l[0][r] * d0 + l[1][r] * d1) + l[2][r] * d2;
            }
        }
    }
}

#[inline(always)]
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

    #[inline(always)]
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

/// The columns of a control texture (one per texel x) interpolated in y and z at one row's texel y and z: for
/// column i, `[F(i)ₓ, F(i)ᵧ, F(i)₂, 0, Sₓ, Sᵧ, S₂, 0]` with the slope S = F(i + 1) − F(i) (0 at the last column, which
/// the clamp never leaves), so that a voxel reads one 32-byte row.
struct ControlColumns(Vec<[f32; 8]>);

impl ControlColumns {
    fn new(texels_x: usize) -> Self {
        Self(vec![[0.0; 8]; texels_x])
    }
}

/// The control texture's clamp-to-edge trilinear displacement at texel coordinates (xᵢ, y, z) of a row along the
/// texture's x axis: first each texel column's value at (y, z) (the lerp in y, then in z, as the shader orders
/// them), once per row; then per voxel the lerp in x between its two columns, F(i₀) + f·(F(i₀ + 1) − F(i₀)): one
/// table row and one multiply-add per component instead of the shader's seven lerps. The same trilinear function as
/// [`ControlCursor::displacement`] in another order: equal up to f32 rounding (exactly equal for a constant texture).
#[inline(always)]
fn control_along_x(
    dims: [usize; 3],
    texels: &[[f32; 4]],
    x: &[f32],
    [y, z]: [f32; 2],
    columns: &mut ControlColumns,
    out: &mut [Vec<f32>; 3],
) {
    let [nx, ny, nz] = dims;
    // As in the cursor: clamp to the texel centres, truncate (the floor, as c ≥ 0), step to the next texel unless
    // at the last.
    let at = |c: f32, n: usize| {
        let c = c.max(0.0).min((n - 1) as f32);
        let i0 = c as usize;
        (i0, c - i0 as f32, usize::from(i0 + 1 < n))
    };
    let (y0, fy, step_y) = at(y, ny);
    let (z0, fz, step_z) = at(z, nz);
    let (dy, dz) = (step_y * nx, step_z * nx * ny);
    let row = nx * (y0 + ny * z0);
    let columns = &mut columns.0[..nx];
    for (i, column) in columns.iter_mut().enumerate() {
        let t = |offset: usize| texels[row + i + offset];
        let v = lerp3(lerp3(t(0), t(dy), fy), lerp3(t(dz), t(dy + dz), fy), fz);
        *column = [v[0], v[1], v[2], 0.0, 0.0, 0.0, 0.0, 0.0];
    }
    for i in 1..nx {
        let next = columns[i];
        let c = &mut columns[i - 1];
        for a in 0..3 {
            c[4 + a] = next[a] - c[a];
        }
    }
    let last = (nx - 1) as f32;
    let n = x.len();
    let [d0, d1, d2] = out;
    let d = d0[..n].iter_mut().zip(d1[..n].iter_mut()).zip(d2[..n].iter_mut());
    for (((d0, d1), d2), &x) in d.zip(x) {
        let c = x.max(0.0).min(last);
        // 0 ≤ c < 2³¹: the i32 cast is the truncation, without the saturation checks of a cast to usize.
        let i0 = c as i32;
        let f = c - i0 as f32;
        let v = &columns[i0 as usize];
        *d0 = v[0] + f * v[4];
        *d1 = v[1] + f * v[5];
        *d2 = v[2] + f * v[6];
    }
}

/// [`TpsLocal::displacement`] at the voxels (x, y, z)ᵢ of one row (local mm, structure of arrays).
///
/// The cost is N square roots per voxel, so the kernel is built for them: each centre is one pass over the row (a
/// loop the compiler vectorises, square roots included), and when the row runs along x (`along_x`: all y equal, all z
/// equal, as on the usual axis-aligned target grid) each centre's dy² + dz² is computed once per row, which is why the
/// canonical order of the squared distance is dx² + (dy² + dz²). With [`Isa::Portable`] the result equals
/// [`TpsLocal::displacement`] bit for bit; rows along x with [`Isa::Avx2Fma`] go through [`simd::centres_along_x`]
/// instead (the same correctly rounded square roots, but fused multiply-adds, so each term may differ by one f32
/// rounding).
#[inline(always)]
pub(crate) fn tps_row(tps: &TpsLocal, [x, y, z]: [&[f32]; 3], along_x: bool, isa: Isa, out: &mut [Vec<f32>; 3]) {
    let n = x.len();
    let (y, z) = (&y[..n], &z[..n]);
    let (l, o) = (&tps.linear_minus_identity, &tps.offset_mm);
    for (r, dr) in out.iter_mut().enumerate() {
        for (d, ((x, y), z)) in dr[..n].iter_mut().zip(x.iter().zip(y).zip(z)) {
            *d = ((l[r][0] * x + l[r][1] * y) + l[r][2] * z) + o[r];
        }
    }
    let [d0, d1, d2] = out;
    let (d0, d1, d2) = (&mut d0[..n], &mut d1[..n], &mut d2[..n]);
    if n == 0 {
        return;
    }
    #[cfg(target_arch = "x86_64")]
    if along_x && isa == Isa::Avx2Fma {
        #[allow(unsafe_code, reason = "a kernel built for AVX2 and FMA")]
        // SAFETY: `Isa::Avx2Fma` is only detected on CPUs with AVX2 and FMA.
        unsafe {
            simd::centres_along_x(tps, x, [y[0], z[0]], [d0, d1, d2]);
        }
        return;
    }
    let _ = isa;
    for (p, w) in tps.centres_local.iter().zip(&tps.weights) {
        let accumulate = |((d0, d1), d2): ((&mut f32, &mut f32), &mut f32), radius: f32| {
            *d0 += w[0] * radius;
            *d1 += w[1] * radius;
            *d2 += w[2] * radius;
        };
        let d = d0.iter_mut().zip(d1.iter_mut()).zip(d2.iter_mut());
        if along_x {
            let (dy, dz) = (y[0] - p[1], z[0] - p[2]);
            let yz = dy * dy + dz * dz;
            for (d, x) in d.zip(x) {
                let dx = x - p[0];
                accumulate(d, (dx * dx + yz).sqrt());
            }
        } else {
            for (d, ((x, y), z)) in d.zip(x.iter().zip(y).zip(z)) {
                let (dx, dy, dz) = (x - p[0], y - p[1], z - p[2]);
                accumulate(d, (dx * dx + (dy * dy + dz * dz)).sqrt());
            }
        }
    }
}

/// The TPS kernel for x86-64 with AVX2 and FMA.
#[cfg(target_arch = "x86_64")]
mod simd {
    use std::arch::x86_64::{__m256, _mm256_fmadd_ps, _mm256_set1_ps, _mm256_sqrt_ps, _mm256_sub_ps};

    use crate::pullback::TpsLocal;

    /// Voxels per block: two registers, so that a block's six accumulators, its positions and one centre's
    /// broadcasts stay in the sixteen registers for the whole loop over the centres.
    const BLOCK: usize = 16;

    /// Adds Σᵢ wᵢ ‖x − pᵢ‖ to `d` along a row whose voxels share y and z, 16 voxels at a time with the centres in
    /// the inner loop: ‖·‖ = √(fma(dx, dx, dy² + dz²)) with each centre's dy² + dz² computed once for the row, and
    /// the weights accumulated by fused multiply-adds. The square root is the correctly rounded `vsqrtps`: the
    /// reciprocal-square-root estimate with a Newton step measured slower on this kernel, which is bound by the
    /// square-root unit (`docs/benchmarks.md`). A short last block is padded with copies of the last voxel.
    #[target_feature(enable = "avx2,fma")]
    pub(super) fn centres_along_x(tps: &TpsLocal, x: &[f32], [y, z]: [f32; 2], d: [&mut [f32]; 3]) {
        let yz: Vec<f32> = tps
            .centres_local
            .iter()
            .map(|p| {
                let (dy, dz) = (y - p[1], z - p[2]);
                dy * dy + dz * dz
            })
            .collect();
        let [d0, d1, d2] = d;
        let n = x.len();
        let mut start = 0;
        while start < n {
            let len = (n - start).min(BLOCK);
            let block = start..start + len;
            let pad = |v: &[f32]| -> [__m256; 2] {
                if let Ok(full) = <[f32; BLOCK]>::try_from(v) {
                    return bytemuck::cast(full);
                }
                let mut a = [v[len - 1]; BLOCK];
                a[..len].copy_from_slice(v);
                bytemuck::cast(a)
            };
            let [x0, x1] = pad(&x[block.clone()]);
            let mut acc = [pad(&d0[block.clone()]), pad(&d1[block.clone()]), pad(&d2[block.clone()])];
            for ((p, w), &s) in tps.centres_local.iter().zip(&tps.weights).zip(&yz) {
                let (px, s) = (_mm256_set1_ps(p[0]), _mm256_set1_ps(s));
                let w = [_mm256_set1_ps(w[0]), _mm256_set1_ps(w[1]), _mm256_set1_ps(w[2])];
                for (h, x) in [x0, x1].into_iter().enumerate() {
                    let dx = _mm256_sub_ps(x, px);
                    let r = _mm256_sqrt_ps(_mm256_fmadd_ps(dx, dx, s));
                    for (a, w) in acc.iter_mut().zip(&w) {
                        a[h] = _mm256_fmadd_ps(*w, r, a[h]);
                    }
                }
            }
            for (a, d) in acc.iter().zip([&mut *d0, &mut *d1, &mut *d2]) {
                let a: [f32; BLOCK] = bytemuck::cast(*a);
                match <&mut [f32; BLOCK]>::try_from(&mut d[block.clone()]) {
                    Ok(full) => *full = a,
                    Err(_) => d[block.clone()].copy_from_slice(&a[..len]),
                }
            }
            start += BLOCK;
        }
    }
}

/// Catmull-Rom weights of the taps at −1, 0, 1, 2 (the shader's `catmull_rom`).
#[inline(always)]
fn catmull_rom(t: f32) -> [f32; 4] {
    [
        t * (-0.5 + t * (1.0 - 0.5 * t)),
        1.0 + t * t * (-2.5 + 1.5 * t),
        t * (0.5 + t * (2.0 - 1.5 * t)),
        t * t * (-0.5 + 0.5 * t),
    ]
}

#[inline(always)]
fn weighted4<A: Acc>(w: [f32; 4], v: [A; 4]) -> A {
    ((A::weight(w[0]) * v[0] + A::weight(w[1]) * v[1]) + A::weight(w[2]) * v[2]) + A::weight(w[3]) * v[3]
}

#[inline(always)]
fn lerp<A: Acc>(a: A, b: A, f: f32) -> A {
    a + A::weight(f) * (b - a)
}

/// ⌊x⌋ for finite |x| < 2³¹, exactly `f32::floor` (which is a libm call on x86-64 without SSE4.1).
#[inline(always)]
fn floor_i32(x: f32) -> i32 {
    let t = x as i32;
    t - i32::from(t as f32 > x)
}

/// Whether `s` lies in the box of voxel edges, −½ ≤ sₐ ≤ nₐ − ½ (false for NaN).
#[inline(always)]
fn inside(s: [f32; 3], n: [f32; 3]) -> bool {
    let within = |a: usize| s[a] >= -0.5 && s[a] <= n[a] - 0.5;
    within(0) && within(1) && within(2)
}

/// Voxels per block of the trilinear lane loops.
const LANES: usize = 8;

/// A full block of [`LANES`] voxels whose trilinear taps (cell corners ⌊s⌋ and ⌊s⌋ + 1 on every axis) all lie
/// inside the source: the index of each lane's first tap and its fractions.
struct TrilinearLanes {
    base: [usize; LANES],
    f: [[f32; LANES]; 3],
}

impl TrilinearLanes {
    /// `None` for a short block or when a lane needs the edge handling (outside, clamped or NaN).
    #[inline(always)]
    fn new(block: [&[f32]; 3], last: [isize; 3], stride: [usize; 3]) -> Option<Self> {
        // 2²³: adding and subtracting it rounds 0 ≤ x < 2²² to the nearest integer, and the integer is then the
        // low mantissa bits of x + 2²³. Floats, compares and bit operations only, so the lane loops vectorise (a
        // saturating `as` cast does not); the results equal `floor_i32` and `x − ⌊x⌋` exactly.
        const MAGIC: f32 = 8_388_608.0;
        let block: [&[f32; LANES]; 3] =
            [block[0].try_into().ok()?, block[1].try_into().ok()?, block[2].try_into().ok()?];
        if last.iter().any(|&l| l >= 1 << 22) {
            return None;
        }
        let mut s0 = [[0u32; LANES]; 3];
        let mut f = [[0.0f32; LANES]; 3];
        let mut interior = [true; LANES];
        for a in 0..3 {
            // 0 ≤ ⌊s⌋ < n − 1 ⟺ 0 ≤ s < n − 1 (false for NaN); this implies −½ ≤ s ≤ n − ½, inside.
            let limit = last[a] as f32;
            for lane in 0..LANES {
                let x = block[a][lane];
                interior[lane] &= x >= 0.0 && x < limit;
                let x = if interior[lane] { x } else { 0.0 };
                let nearest = (x + MAGIC) - MAGIC;
                let floor = if nearest > x { nearest - 1.0 } else { nearest };
                s0[a][lane] = (floor + MAGIC).to_bits() & 0x7f_ffff;
                f[a][lane] = x - floor;
            }
        }
        if interior.contains(&false) {
            return None;
        }
        let base = std::array::from_fn(|lane| {
            s0[0][lane] as usize + stride[1] * s0[1][lane] as usize + stride[2] * s0[2][lane] as usize
        });
        Some(Self { base, f })
    }
}

#[inline(always)]
/// Samples `source` at the continuous indices `positions`, writing one output row. Taps are addressed by per-axis
/// offsets (clamped index × stride) summed, so a tap costs two additions.
fn sample_row<S: Sample, O: Sample>(
    interpolation: Interpolation,
    source: &[S],
    dims: [usize; 3],
    [sx, sy, sz]: [&[f32]; 3],
    out: &mut [O],
    outside: O,
) {
    let len = out.len();
    let (sx, sy, sz) = (&sx[..len], &sy[..len], &sz[..len]);
    let positions = sx.iter().zip(sy).zip(sz).map(|((x, y), z)| [*x, *y, *z]);
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
                *o = if inside(s, n) {
                    let q: [usize; 3] = std::array::from_fn(|a| offset(a, floor_i32(s[a] + 0.5) as isize));
                    store(at(q[0] + q[1] + q[2]))
                } else {
                    outside
                };
            }
        }
        Interpolation::Trilinear => {
            let dy = stride[1];
            let dz = stride[2];
            let taps = [0, 1, dy, dy + 1, dz, dz + 1, dz + dy, dz + dy + 1];
            for (b, o_block) in out.chunks_mut(LANES).enumerate() {
                let block = b * LANES..b * LANES + o_block.len();
                let s_block = [&sx[block.clone()], &sy[block.clone()], &sz[block.clone()]];
                // Lanes: a block of voxels whose eight taps all lie inside the source goes through SIMD-friendly
                // lane loops (the same operations per voxel as the scalar path below, in the same order).
                if let Some(lanes) = TrilinearLanes::new(s_block, last, stride)
                    && let Ok(o_block) = <&mut [O; LANES]>::try_from(&mut *o_block)
                {
                    let mut v = [[S::Acc::weight(0.0); LANES]; 8];
                    // The taps in pairs along x: [x0, x1] of each of the four rows.
                    let (rows, _) = v.as_chunks_mut::<2>();
                    for ([v0, v1], offset) in rows.iter_mut().zip(taps.iter().step_by(2)) {
                        for ((v0, v1), base) in v0.iter_mut().zip(v1.iter_mut()).zip(&lanes.base) {
                            let at = base + offset;
                            let pair = &source[at..at + 2];
                            *v0 = pair[0].acc();
                            *v1 = pair[1].acc();
                        }
                    }
                    let f = &lanes.f;
                    for (lane, o) in o_block.iter_mut().enumerate() {
                        let x00 = lerp(v[0][lane], v[1][lane], f[0][lane]);
                        let x10 = lerp(v[2][lane], v[3][lane], f[0][lane]);
                        let x01 = lerp(v[4][lane], v[5][lane], f[0][lane]);
                        let x11 = lerp(v[6][lane], v[7][lane], f[0][lane]);
                        *o = store(lerp(lerp(x00, x10, f[1][lane]), lerp(x01, x11, f[1][lane]), f[2][lane]));
                    }
                    continue;
                }
                for (o, s) in o_block.iter_mut().zip(positions.clone().skip(block.start)) {
                    if !inside(s, n) {
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
        }
        Interpolation::CatmullRom => {
            for (o, s) in out.iter_mut().zip(positions) {
                if !inside(s, n) {
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
    fn row_kernel_is_tps_local_bit_for_bit() {
        let tps = TpsLocal {
            origin_ref: [0.0; 3],
            linear_minus_identity: [[0.01, -0.02, 0.003], [0.0, 0.015, -0.01], [0.02, 0.0, -0.005]],
            offset_mm: [1.5, -0.25, 3.0],
            centres_local: vec![[10.0, -20.0, 5.0], [-30.0, 12.5, 40.0], [0.0, 0.0, -7.0], [-12.3, 4.0, 0.5]],
            weights: vec![[0.01, -0.03, 0.02], [-0.02, 0.01, 0.0], [0.01, 0.02, -0.02], [0.0, -0.01, 0.01]],
        };
        let base = [-20.0, 4.0, 0.5];
        // Along x (dy² + dz² per row, and a voxel on a centre: radius 0) and oblique; lengths that are not a
        // multiple of a SIMD register.
        for step in [[3.7f32, 0.0, 0.0], [3.7, -1.0, 0.5], [0.0, 0.0, 1.25]] {
            for len in [1, 13, 16, 37] {
                let x: [Vec<f32>; 3] =
                    std::array::from_fn(|a| (0..len).map(|i| base[a] + i as f32 * step[a]).collect());
                let mut out = std::array::from_fn(|_| vec![f32::NAN; len]);
                let along_x = step[1] == 0.0 && step[2] == 0.0;
                tps_row(&tps, [&x[0], &x[1], &x[2]], along_x, Isa::Portable, &mut out);
                for i in 0..len {
                    let expected = tps.displacement([x[0][i], x[1][i], x[2][i]]);
                    assert_eq!([out[0][i], out[1][i], out[2][i]], expected, "step {step:?}, voxel {i} of {len}");
                }
            }
        }
    }

    #[test]
    #[cfg(target_arch = "x86_64")]
    fn simd_row_kernel_agrees_with_tps_local_to_f32_rounding() {
        if Isa::detect() != Isa::Avx2Fma {
            eprintln!("no AVX2 + FMA on this CPU: nothing to compare");
            return;
        }
        let centres: Vec<[f32; 3]> = (0..37)
            .map(|c| [(c * 37 % 200) as f32 - 100.0, (c * 91 % 160) as f32 - 80.0, (c * 53 % 120) as f32 - 60.0])
            .collect();
        let weights: Vec<[f32; 3]> = (0..37)
            .map(|c| [((c % 7) as f32 - 3.0) * 0.02, ((c % 5) as f32 - 2.0) * 0.03, (c % 3) as f32 * -0.01])
            .collect();
        // A voxel exactly on the first centre: radius 0, not NaN.
        let first = centres[0];
        let tps = TpsLocal {
            origin_ref: [0.0; 3],
            linear_minus_identity: [[0.01, -0.02, 0.003], [0.0, 0.015, -0.01], [0.02, 0.0, -0.005]],
            offset_mm: [1.5, -0.25, 3.0],
            centres_local: centres,
            weights,
        };
        for len in [1, 7, 16, 45, 256] {
            let x: Vec<f32> = (0..len).map(|i| first[0] - 3.0 * i as f32).collect();
            let (y, z) = (vec![first[1]; len], vec![first[2]; len]);
            let mut out = std::array::from_fn(|_| vec![f32::NAN; len]);
            tps_row(&tps, [&x, &y, &z], true, Isa::Avx2Fma, &mut out);
            for i in 0..len {
                let p = [x[i], y[i], z[i]];
                let expected = tps.displacement(p);
                // Each of the 37 terms is rounded differently (fused multiply-adds): a few f32 roundings of the
                // largest term, |w|·r ≤ 0.06 · 300 mm.
                let scale: f32 = tps
                    .centres_local
                    .iter()
                    .zip(&tps.weights)
                    .map(|(c, w)| {
                        w.iter().map(|v| v.abs()).fold(0.0, f32::max)
                            * (0..3).map(|a| (p[a] - c[a]).powi(2)).sum::<f32>().sqrt()
                    })
                    .sum();
                for a in 0..3 {
                    let got = out[a][i];
                    assert!(got.is_finite(), "voxel {i} of {len}: {got}");
                    assert!(
                        (got - expected[a]).abs() <= 4.0 * f32::EPSILON * (scale + 10.0),
                        "voxel {i} of {len}, axis {a}: {got} vs {}",
                        expected[a]
                    );
                }
            }
        }
    }

    #[test]
    fn trilinear_lanes_equal_the_scalar_path_bit_for_bit() {
        let dims = [9, 7, 5];
        let source: Vec<f32> =
            (0..dims.iter().product::<usize>()).map(|i| ((i * 7919) % 1013) as f32 * 0.37 - 90.0).collect();
        // Positions inside, on the edge (clamped), outside and NaN, mixed so that some blocks of eight take the
        // lanes and some the scalar path.
        let len = 8 * 40;
        let mut xyz: [Vec<f32>; 3] = Default::default();
        for i in 0..len {
            let t = i as f32;
            let mut p =
                [(t * 0.618_034).fract() * 8.9 - 0.3, (t * 0.414_214).fract() * 6.5, (t * 0.302_776).fract() * 4.2];
            if i >= 8 * 20 {
                // The second half: whole blocks well inside, where the lanes run.
                p = [p[0] * 0.8 + 0.1, p[1] * 0.8 + 0.1, p[2] * 0.7 + 0.1];
            }
            if i == 13 {
                p[1] = f32::NAN;
            }
            for a in 0..3 {
                xyz[a].push(p[a]);
            }
        }
        let mut row = vec![0.0f32; len];
        sample_row(Interpolation::Trilinear, &source, dims, [&xyz[0], &xyz[1], &xyz[2]], &mut row, -1.0);
        let mut lanes_used = 0;
        for i in 0..len {
            // One voxel at a time: always the scalar path.
            let mut one = [0.0f32];
            sample_row(
                Interpolation::Trilinear,
                &source,
                dims,
                [&xyz[0][i..=i], &xyz[1][i..=i], &xyz[2][i..=i]],
                &mut one,
                -1.0,
            );
            assert_eq!(row[i].to_bits(), one[0].to_bits(), "voxel {i}");
        }
        for b in 0..len / 8 {
            let block = b * 8..b * 8 + 8;
            let s = [&xyz[0][block.clone()], &xyz[1][block.clone()], &xyz[2][block]];
            lanes_used += usize::from(TrilinearLanes::new(s, [8, 6, 4], [1, 9, 63]).is_some());
        }
        assert!(lanes_used >= 10 && lanes_used < len / 8, "{lanes_used} blocks through the lanes");
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

    /// A smooth, non-constant texture of displacements of up to ±`amplitude_mm`.
    fn smooth_texels(dims: [usize; 3], amplitude_mm: f32) -> Vec<[f32; 4]> {
        let mut texels = Vec::new();
        for k in 0..dims[2] {
            for j in 0..dims[1] {
                for i in 0..dims[0] {
                    let (x, y, z) = (i as f32 * 0.37, j as f32 * 0.23, k as f32 * 0.31);
                    let v = amplitude_mm * (x + 2.0 * y).sin();
                    texels.push([v, amplitude_mm * (y - z).cos(), amplitude_mm * (0.5 * x * z).sin() * 0.8, 0.0]);
                }
            }
        }
        texels
    }

    /// The largest difference allowed between [`control_along_x`] and the per-voxel [`ControlCursor`] (the
    /// shader's order), in units of f32::EPSILON · max |texel|: a few roundings of the displacement. For
    /// displacements up to 10 mm and a source spacing of 0.5 mm or more that is under 2·10⁻⁵ voxel in the source
    /// position, a fifth of the 10⁻⁴ voxel to which `crates/gpu/tests/export.rs` holds the CPU and the GPU against
    /// an f64 oracle.
    const CONTROL_REORDER_TOLERANCE_EPS: f32 = 8.0;

    #[test]
    fn control_along_x_is_the_per_voxel_cursor_to_f32_rounding() {
        let dims = [9, 6, 5];
        let amplitude_mm = 8.0;
        let texels = smooth_texels(dims, amplitude_mm);
        let max_abs = texels.iter().flat_map(|t| t[..3].iter().map(|v| v.abs())).fold(0.0, f32::max);
        let tolerance_mm = CONTROL_REORDER_TOLERANCE_EPS * f32::EPSILON * max_abs;
        let mut columns = ControlColumns::new(dims[0]);
        let mut worst = 0.0f32;
        // Rows inside the texture, on its edges, beyond them (clamped), and with a NaN start; steps of a quarter texel
        // (a 64³ texture over a 256³ grid) and odd ones.
        for (row, (y, z)) in [(0.0, 0.0), (2.3, 1.7), (5.0, 4.0), (-1.5, 7.2), (3.999, 0.001)].into_iter().enumerate() {
            for (start, step) in [(0.0f32, 0.25f32), (-1.3, 0.37), (0.1, 0.0517), (f32::NAN, 0.5)] {
                let x: Vec<f32> = (0..57).map(|i| start + i as f32 * step).collect();
                let mut out = std::array::from_fn(|_| vec![f32::NAN; x.len()]);
                control_along_x(dims, &texels, &x, [y, z], &mut columns, &mut out);
                let mut cursor = ControlCursor::new(dims, &texels);
                for (i, &xi) in x.iter().enumerate() {
                    let expected = cursor.displacement([xi, y, z]);
                    for a in 0..3 {
                        let diff = (out[a][i] - expected[a]).abs();
                        worst = worst.max(diff);
                        assert!(diff <= tolerance_mm, "row {row}, x {xi}, axis {a}: {} vs {}", out[a][i], expected[a]);
                    }
                }
            }
        }
        // Reordering does change some roundings: the law is a tolerance, not an identity (so the test can fail).
        assert!(worst > 0.0, "worst {worst}");
    }

    #[test]
    fn control_along_x_gives_a_constant_texture_exactly() {
        let constant = [0.1f32, -3.7, 1e-3, 0.0];
        let dims = [5, 4, 3];
        let texels = vec![constant; 5 * 4 * 3];
        let mut columns = ControlColumns::new(dims[0]);
        let x: Vec<f32> = (0..40).map(|i| i as f32 * 0.17 - 1.0).collect();
        let mut out = std::array::from_fn(|_| vec![f32::NAN; x.len()]);
        control_along_x(dims, &texels, &x, [1.3, 2.9], &mut columns, &mut out);
        for (a, out) in out.iter().enumerate() {
            assert!(out.iter().all(|&d| d == constant[a]), "axis {a}: {out:?}");
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
