//! Export of the warped moving volume: the moving volume v resampled onto a target grid through the pull-back u,
//!
//! v′(x) = v(u(x)),   x in ref (fixed LPS) mm, u(x) = x + d(x) in moving LPS mm,
//!
//! the form in which the renderer shows the warp (Brunet, Nowak & Gleicher 2006 §3), evaluated once per target voxel.
//! Resampling is a pull-back, as in ITK's `ResampleImageFilter`: every output voxel asks where it comes from.
//!
//! # One request, two paths
//!
//! An [`ExportRequest`] (plain data: [`SourceVolume`], [`TargetGrid`], [`PullBack`], [`Interpolation`],
//! [`OutputType`], the outside value) is run either by [`export_cpu`] (rayon, every machine) or by
//! [`ExportPass::run`] (a wgpu compute pass, `shaders/export.wgsl`). Both evaluate, per target voxel (i, j, k):
//!
//! 1. s = S · (i, j, k) with S = `source_index_from_target_index` = `index_from_lps` · `lps_from_index` (the identity
//!    part of u), composed in f64; entries within 10⁻⁹ (relative) of an integer are snapped to it, so that a grid
//!    equal to the source's, or shifted by whole voxels, lands exactly on voxel centres;
//! 2. s += L · d, with L the linear part of the source's `index_from_lps` and d = u(x) − x the pull-back's
//!    displacement in mm: [`PullBack::Identity`] (d = 0), [`PullBack::Control`] (trilinear, clamp-to-edge lookup of a
//!    control texture, exactly [`crate::PreparedControl::displacement`]'s convention) or [`PullBack::Tps`] (the TPS
//!    evaluated per voxel in its local f32 form, [`crate::TpsLocal`]);
//! 3. **inside** ⇔ −½ ≤ sₐ ≤ nₐ − ½ on every axis (the box of voxel edges, ITK's continuous-index buffer test);
//!    outside voxels get [`ExportRequest::outside_value`] (0 by default; CT users may want −1024);
//! 4. inside voxels are interpolated with clamp-to-edge taps: [`Interpolation::Nearest`] (⌊s + ½⌋),
//!    [`Interpolation::Trilinear`], or [`Interpolation::CatmullRom`].
//!
//! Positions, weights and displacements are f32 on both paths, with the same operations in the same order (see
//! `shaders/export.wgsl`); sample values are accumulated in f32, or in f64 on the CPU for u32, i32 and f64 samples
//! (so that every sample enters exactly; the GPU path refuses those samples unless every one is exact in f32:
//! [`ExportSamples::exact_in_f32`]). On lavapipe (Vulkan and GL) the two paths agree bit for bit; other devices may
//! contract to FMA or round `sqrt` differently, which moves positions by ~10⁻⁶ voxel (the tests allow 10⁻⁴).
//!
//! Since d = 0 adds exactly zero and every kernel's weights are exactly (…, 0, 1, 0, …) at a voxel centre, the
//! identity reproduces the source bit for bit (except that −0.0 may come out as +0.0), and a whole-voxel
//! translation reproduces the shifted volume exactly when the shift in mm and the source's `index_from_lps` are exact
//! in f32 (power-of-two spacings; otherwise within ~10⁻⁷ voxel). Non-finite float samples spread to every output
//! whose taps reach them (0 · NaN = NaN), as in any linear filter.
//!
//! # The cubic: Catmull-Rom
//!
//! Catmull-Rom (the cubic convolution kernel with a = −½, Keys 1981) interpolates the samples, so it needs no
//! prefilter, keeps the identity exact and can be evaluated slab by slab from the raw samples on both paths. A cubic
//! B-spline would need the Unser recursive prefilter over the whole volume first (another full copy in f32, and
//! round-off that breaks exactness at the voxel centres). Catmull-Rom overshoots at steps (by up to 7.4 % of the
//! step: −½ t (1 − t)² at t = ⅓), which is why integer outputs are clamped.
//!
//! # Output
//!
//! [`OutputType::F32`], or [`OutputType::Source`]: the source's sample type, the interpolated value rounded **half to
//! even** (IEEE 754's default, WGSL's `round`, numpy's `rint`) and clamped to the type's range (on the GPU in the
//! shader, from the same f32). Non-finite outside values are refused for integer outputs; the outside value is
//! converted once, on the host, by the same rule.
//!
//! # Slabs and limits
//!
//! The target is processed in z-slabs ([`ExportRequest::slab_slices`], or automatic), and the progress callback is
//! called after each slab with the slices done so far; returning `false` cancels with
//! [`crate::GpuError::Cancelled`]. On the GPU each slab's output, stored in the output's own type, fits
//! `max_storage_buffer_binding_size` and [`ExportPass::SLAB_BUDGET_BYTES`], so outputs much larger than one binding
//! (a 512 × 512 × 1000 CT) work, and its work fits [`ExportPass::WORK_BUDGET`], so no dispatch runs long; one target
//! slice must fit (4096 × 4096 does). Up to [`ExportPass::SLABS_IN_FLIGHT`] slabs are queued at once, so the GPU
//! computes the next slab while the host copies one out, and every wait for a slab is bounded
//! ([`ExportPass::SLAB_WAIT_LIMIT`]): a stalled device is an error, never a hang. The source is one 3-D texture in
//! its own type (`R16Sint` for i16, `R8Uint` for u8, …): at most `max_texture_dimension_3d` (usually 2048) per axis
//! and [`ExportPass::MAX_SOURCE_BYTES`]; larger sources are a [`crate::GpuError::Unsupported`] error naming the CPU
//! path, which has no such limit. Outputs beyond [`ExportRequest::max_output_bytes`] (default
//! [`DEFAULT_MAX_OUTPUT_BYTES`], 16 GiB) are refused before anything is allocated.
//!
//! # Which path
//!
//! [`choose_path`] says which of the two is expected to finish first for a request on this machine (the CPU without
//! a hardware GPU, for small outputs and for cheap kernels on many threads; the GPU otherwise); `warpbench warp
//! --backend auto` follows it.

mod choice;
mod cpu;
mod gpu;
mod plan;
mod request;
mod sample;

pub use choice::{
    CPU_KERNEL_NS, CPU_PULLBACK_NS, CPU_TPS_CENTRE_NS, ExportDevice, ExportPath, GPU_FIXED_MS, GPU_LINK_BYTES_PER_NS,
    GPU_TPS_CENTRE_NS, GPU_VOXEL_NS, PathChoice, choose_path, cpu_estimate_ms, gpu_estimate_ms,
};
pub use cpu::export_cpu;
pub use gpu::{ExportPass, ExportUniforms, INTERFACE, SHADER};
pub use request::{
    DEFAULT_MAX_OUTPUT_BYTES, ExportRequest, ExportSamples, ExportedSamples, ExportedVolume, Interpolation,
    MAX_DIMENSION, OutputType, Progress, PullBack, SampleType, SourceVolume, TargetGrid,
};
