//! The export of the warped volume (`warpbench_gpu::export`): exact laws (the identity is bit-identical, whole-voxel
//! translations are exact shifts, rounding is half to even and clamps, for every sample type, which the GPU uploads
//! and stores in its own type), the CPU path and the GPU path against each other and against a brute-force f64
//! oracle written here from the formulas, slabs, progress and cancellation, concurrent exports, and bad input. GPU
//! checks skip without an adapter unless REQUIRE_GPU_ADAPTER=1.
//!
//! No test here compares hardware-filtered output: the export reads texels with `textureLoad` and weights them in f32
//! on every device (integer textures cannot be filtered at all), so the fixed-point sub-texel weights of hardware
//! filtering (8 bits on NVIDIA, 4 allowed by Vulkan) never enter, and the tolerances below come from f32 round-off of
//! positions alone ([`POSITION_TOLERANCE_VOX`]). The exact laws hold bit for bit on any conformant device.
//!
//! Every test runs under [`hang_guard`]: a test that has not finished after [`HANG_GUARD`] fails and names what its
//! threads were doing (creating a device, which slab of an export, dropping the device), instead of stalling the
//! whole test binary as two of these tests did on a shared NVIDIA H200 (issue 28).

#![allow(clippy::float_cmp, reason = "the laws tested here (identity, shifts, rounding, the outside rule) are exact")]

mod common;

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Mutex, PoisonError, mpsc};
use std::thread;
use std::time::Duration;

use glam::{DMat4, DVec3};
use warpbench_gpu::export::{ExportPass, ExportUniforms};
use warpbench_gpu::{
    ControlDesc, ExportRequest, ExportSamples, ExportedSamples, ExportedVolume, FeatureRequest, GpuContext, GpuError,
    Interpolation, OutputType, Progress, PullBack, SourceVolume, TargetGrid, TpsDesc, export_cpu,
};

const KERNELS: [Interpolation; 3] = [Interpolation::Nearest, Interpolation::Trilinear, Interpolation::CatmullRom];

/// Largest disagreement in source position (voxels) between the two f32 paths, or between either and the f64
/// oracle: the positions are f32 sums of a few terms of magnitude ≤ 100 (indices and local mm), each rounded to
/// 2⁻²⁴ relative (≈ 6·10⁻⁶ per term); GPUs may add FMA contraction and a sqrt within a few ulp. Measured against the
/// oracle: ≈ 6·10⁻⁶ voxel (7.8·10⁻³ HU at gradients of ≈ 1200 HU/voxel); 10⁻⁴ voxel leaves a margin of 16×.
const POSITION_TOLERANCE_VOX: f64 = 1e-4;

fn no_progress() -> impl FnMut(Progress) -> bool {
    |_| true
}

// ---------------------------------------------------------------------------------------------------------------
// The hang guard.

/// How long a test may run before it counts as hung: far beyond what the slowest takes on a loaded 2-core machine
/// with lavapipe (seconds). A bound on a wait that never returns, not a timing: the GPU path polls with deadlines of
/// its own, so a stall must surface as an error, or here.
const HANG_GUARD: Duration = Duration::from_mins(1);

/// What each thread of a guarded test is doing, by thread name (a test's threads are named after it).
static PHASES: Mutex<BTreeMap<String, String>> = Mutex::new(BTreeMap::new());

/// Records what the calling thread is doing now, for [`hang_guard`]'s message.
fn phase(what: impl Into<String>) {
    let name = thread::current().name().unwrap_or("unnamed").to_owned();
    PHASES.lock().unwrap_or_else(PoisonError::into_inner).insert(name, what.into());
}

/// Runs `body` on a thread named `test` and fails if it has not returned within [`HANG_GUARD`], with the last
/// [`phase`] of each of the test's threads (`test` and `test/…`). A panic in `body` is the test's panic.
fn hang_guard(test: &'static str, body: impl FnOnce() + Send + 'static) {
    let (finished, answer) = mpsc::channel();
    let worker = thread::Builder::new()
        .name(test.to_owned())
        .spawn(move || {
            body();
            let _ = finished.send(());
        })
        .expect("spawn the guarded test");
    match answer.recv_timeout(HANG_GUARD) {
        // Returned, or panicked (the channel closed unanswered): join gives the panic back.
        Ok(()) | Err(mpsc::RecvTimeoutError::Disconnected) => {
            if let Err(panic) = worker.join() {
                std::panic::resume_unwind(panic);
            }
        }
        Err(mpsc::RecvTimeoutError::Timeout) => {
            let phases = PHASES.lock().unwrap_or_else(PoisonError::into_inner);
            let ours: Vec<String> = phases
                .iter()
                .filter(|(name, _)| *name == test || name.starts_with(&format!("{test}/")))
                .map(|(name, what)| format!("{name}: {what}"))
                .collect();
            panic!("{test} hung: not finished after {HANG_GUARD:?}; last phases: {}", ours.join("; "));
        }
    }
}

/// Row-major `lps_from_index` of an axis-aligned grid.
fn axis_grid(spacing: [f64; 3], origin: [f64; 3]) -> [[f64; 4]; 4] {
    let mut m = [[0.0; 4]; 4];
    for a in 0..3 {
        m[a][a] = spacing[a];
        m[a][3] = origin[a];
    }
    m[3][3] = 1.0;
    m
}

/// Row-major `lps_from_index` of a grid of `spacing` rotated by `angle_rad` about z and by `tilt_rad` about x.
fn oblique_grid(spacing: [f64; 3], origin: [f64; 3], angle_rad: f64, tilt_rad: f64) -> [[f64; 4]; 4] {
    let rotation = glam::DMat3::from_rotation_x(tilt_rad) * glam::DMat3::from_rotation_z(angle_rad);
    let mut m = [[0.0; 4]; 4];
    for r in 0..3 {
        for c in 0..3 {
            m[r][c] = rotation.col(c)[r] * spacing[c];
        }
        m[r][3] = origin[r];
    }
    m[3][3] = 1.0;
    m
}

fn matrix(m: &[[f64; 4]; 4]) -> DMat4 {
    DMat4::from_cols_array_2d(m).transpose()
}

/// A deterministic pseudo-random value in [0, 1) for index `i` and `seed` (a 64-bit mix).
fn hash01(i: usize, seed: u64) -> f64 {
    let mut x = (i as u64) ^ seed.wrapping_mul(0x9E37_79B9_7F4A_7C15);
    x = (x ^ (x >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    x = (x ^ (x >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    x ^= x >> 31;
    (x >> 11) as f64 / (1u64 << 53) as f64
}

/// Samples of every type over their full range (for u32 and i32 within ±2²⁴ when `f32_exact`; for f64 values
/// exact in f32 when `f32_exact`), seeded.
fn samples_of_every_type(len: usize, f32_exact: bool) -> Vec<ExportedSamples> {
    let h = |seed| (0..len).map(move |i| hash01(i, seed));
    let wide = if f32_exact { f64::from(1 << 24) } else { f64::from(u32::MAX) };
    vec![
        ExportedSamples::U8(h(1).map(|v| (v * 256.0) as u8).collect()),
        ExportedSamples::I8(h(2).map(|v| (v * 256.0 - 128.0) as i8).collect()),
        ExportedSamples::U16(h(3).map(|v| (v * 65536.0) as u16).collect()),
        ExportedSamples::I16(h(4).map(|v| (v * 65536.0 - 32768.0) as i16).collect()),
        ExportedSamples::U32(h(5).map(|v| (v * wide) as u32).collect()),
        ExportedSamples::I32(h(6).map(|v| ((v - 0.5) * wide) as i32).collect()),
        ExportedSamples::F32(h(7).map(|v| ((v - 0.3) * 5000.0) as f32).collect()),
        ExportedSamples::F64(
            h(8).map(|v| if f32_exact { f64::from(((v - 0.3) * 5000.0) as f32) } else { (v - 0.3) * 5000.0 }).collect(),
        ),
    ]
}

/// A smooth non-linear TPS pull-back about the box [−40, 40]³ mm (displacements of a few mm).
struct Tps {
    centres: Vec<[f64; 3]>,
    weights: Vec<[f64; 3]>,
}

impl Tps {
    fn new() -> Self {
        let centres = vec![
            [-25.0, -20.0, -15.0],
            [20.0, -25.0, 10.0],
            [-15.0, 25.0, 20.0],
            [25.0, 20.0, -20.0],
            [0.0, 5.0, 0.0],
            [5.0, -5.0, 30.0],
        ];
        let weights = vec![
            [0.04, -0.03, 0.02],
            [-0.05, 0.02, 0.03],
            [0.03, 0.04, -0.05],
            [-0.02, -0.05, 0.01],
            [0.06, 0.01, -0.03],
            [-0.06, 0.01, 0.02],
        ];
        Self { centres, weights }
    }

    fn desc(&self) -> TpsDesc<'_> {
        TpsDesc {
            centres_ref: &self.centres,
            weights: &self.weights,
            linear: [[1.02, 0.03, -0.01], [-0.02, 0.97, 0.02], [0.01, -0.03, 1.01]],
            translation: [1.5, -2.0, 0.75],
        }
    }
}

/// The TPS sampled as an n³ control texture over `[min, max]` (texel centres at (a + ½)/n), in f64 then f32.
fn control_texels(tps: &TpsDesc<'_>, n: usize, min: [f64; 3], max: [f64; 3]) -> Vec<f32> {
    let mut out = Vec::with_capacity(4 * n * n * n);
    for c in 0..n {
        for b in 0..n {
            for a in 0..n {
                let f = [a, b, c].map(|t| (t as f64 + 0.5) / n as f64);
                let x: [f64; 3] = std::array::from_fn(|i| min[i] + f[i] * (max[i] - min[i]));
                let u = tps.eval(x);
                out.extend([(u[0] - x[0]) as f32, (u[1] - x[1]) as f32, (u[2] - x[2]) as f32, 0.0]);
            }
        }
    }
    out
}

// ---------------------------------------------------------------------------------------------------------------
// The f64 oracle: positions and values straight from the formulas.

/// u(x) in f64 for the request's pull-back.
fn pullback_f64(pullback: &PullBack<'_>, x: DVec3) -> DVec3 {
    match pullback {
        PullBack::Identity => x,
        PullBack::Tps(t) => DVec3::from_array(t.eval(x.to_array())),
        PullBack::Control(c) => {
            let (min, max) = (DVec3::from_array(c.box_min_ref), DVec3::from_array(c.box_max_ref));
            let n = [0, 1, 2].map(|a| c.dims[a] as f64);
            let t = (x - min) / (max - min) * DVec3::from_array(n) - DVec3::splat(0.5);
            let mut d = DVec3::ZERO;
            let mut i0 = [0usize; 3];
            let mut f = [0.0; 3];
            for a in 0..3 {
                let ta = t[a].clamp(0.0, n[a] - 1.0);
                i0[a] = (ta.floor() as usize).min(c.dims[a].saturating_sub(2));
                f[a] = ta - i0[a] as f64;
            }
            for corner in 0..8 {
                let o = [corner & 1, (corner >> 1) & 1, (corner >> 2) & 1];
                let q: [usize; 3] = std::array::from_fn(|a| (i0[a] + o[a]).min(c.dims[a] - 1));
                let w: f64 = (0..3).map(|a| if o[a] == 1 { f[a] } else { 1.0 - f[a] }).product();
                let idx = 4 * (q[0] + c.dims[0] * (q[1] + c.dims[1] * q[2]));
                d += w * DVec3::new(
                    f64::from(c.texels[idx]),
                    f64::from(c.texels[idx + 1]),
                    f64::from(c.texels[idx + 2]),
                );
            }
            x + d
        }
    }
}

/// The continuous source index of target voxel `ijk`.
fn source_index_f64(request: &ExportRequest<'_>, ijk: [usize; 3]) -> DVec3 {
    let x_ref = matrix(&request.target.lps_from_index).transform_point3(DVec3::from_array(ijk.map(|v| v as f64)));
    let u = pullback_f64(&request.pullback, x_ref);
    matrix(&request.source.lps_from_index).inverse().transform_point3(u)
}

/// The Catmull-Rom kernel k(x) (Keys 1981, a = −½).
fn keys(x: f64) -> f64 {
    let x = x.abs();
    if x < 1.0 {
        1.5 * x * x * x - 2.5 * x * x + 1.0
    } else if x < 2.0 {
        -0.5 * x * x * x + 2.5 * x * x - 4.0 * x + 2.0
    } else {
        0.0
    }
}

/// The value at continuous source index `s`, `None` outside the box of voxel edges.
fn value_f64(samples: &ExportedSamples, dims: [usize; 3], s: DVec3, kernel: Interpolation) -> Option<f64> {
    let n = dims.map(|d| d as f64);
    if (0..3).any(|a| !(s[a] >= -0.5 && s[a] <= n[a] - 0.5)) {
        return None;
    }
    let at = |q: [i64; 3]| {
        let c: [usize; 3] = std::array::from_fn(|a| q[a].clamp(0, dims[a] as i64 - 1) as usize);
        samples.get_f64(c[0] + dims[0] * (c[1] + dims[1] * c[2]))
    };
    let base = [s.x.floor() as i64, s.y.floor() as i64, s.z.floor() as i64];
    let (reach, kernel_weight): (std::ops::RangeInclusive<i64>, fn(f64) -> f64) = match kernel {
        Interpolation::Nearest => {
            return Some(at([0, 1, 2].map(|a| (s[a] + 0.5).floor() as i64)));
        }
        Interpolation::Trilinear => (0..=1, |x: f64| (1.0 - x.abs()).max(0.0)),
        Interpolation::CatmullRom => (-1..=2, keys),
    };
    let mut sum = 0.0;
    for dz in reach.clone() {
        for dy in reach.clone() {
            for dx in reach.clone() {
                let q = [base[0] + dx, base[1] + dy, base[2] + dz];
                let w: f64 = (0..3).map(|a| kernel_weight(s[a] - q[a] as f64)).product();
                sum += w * at(q);
            }
        }
    }
    Some(sum)
}

/// Whether a position error of `POSITION_TOLERANCE_VOX` could change the decision at `s`: the inside test, or for
/// nearest the half-integer between two voxels.
fn near_a_decision(s: DVec3, dims: [usize; 3], kernel: Interpolation) -> bool {
    (0..3).any(|a| {
        let near = |edge: f64| (s[a] - edge).abs() <= POSITION_TOLERANCE_VOX;
        let half = (s[a] - 0.5).round() + 0.5;
        near(-0.5) || near(dims[a] as f64 - 0.5) || (kernel == Interpolation::Nearest && near(half))
    })
}

/// Largest |∂v/∂s| bound of the interpolant: the largest jump between neighbouring samples, times the kernel's
/// derivative bound (1 for trilinear, 1.5 for Catmull-Rom's 4 taps).
fn gradient_bound(samples: &ExportedSamples, dims: [usize; 3]) -> f64 {
    let [nx, ny, nz] = dims;
    let mut jump = 0.0f64;
    for k in 0..nz {
        for j in 0..ny {
            for i in 0..nx {
                let v = samples.get_f64(i + nx * (j + ny * k));
                for (di, dj, dk) in [(1, 0, 0), (0, 1, 0), (0, 0, 1)] {
                    if i + di < nx && j + dj < ny && k + dk < nz {
                        jump = jump.max((samples.get_f64(i + di + nx * (j + dj + ny * (k + dk))) - v).abs());
                    }
                }
            }
        }
    }
    1.5 * jump
}

/// Value tolerance between two evaluations whose positions differ by ≤ `POSITION_TOLERANCE_VOX`: the gradient bound
/// times that, plus the f32 accumulation of up to 64 taps (64 ε |v|max).
fn value_tolerance(samples: &ExportedSamples, dims: [usize; 3]) -> f64 {
    let max_abs = (0..samples.len()).map(|i| samples.get_f64(i).abs()).fold(0.0, f64::max);
    gradient_bound(samples, dims) * POSITION_TOLERANCE_VOX + 64.0 * f64::from(f32::EPSILON) * max_abs
}

/// A device and the export pass; dropping it is a [`phase`] of its own.
struct Gpu(GpuContext, ExportPass);

impl Drop for Gpu {
    fn drop(&mut self) {
        phase("dropping the GPU device");
    }
}

fn gpu() -> Option<Gpu> {
    phase("creating the GPU device");
    let ctx = common::context(FeatureRequest::default())?;
    let pass = ExportPass::new(&ctx).expect("export pass");
    phase("GPU device ready");
    Some(Gpu(ctx, pass))
}

/// The GPU export of `request`, recording each slab as a [`phase`].
fn run_gpu_with(
    gpu: &Gpu,
    request: &ExportRequest<'_>,
    progress: &mut dyn FnMut(Progress) -> bool,
) -> Result<ExportedVolume, GpuError> {
    phase("GPU export: upload and first slabs");
    let result = gpu.1.run(&gpu.0, request, &mut |p| {
        phase(format!("GPU export: {} of {} slices read back", p.slices_done, p.slices_total));
        progress(p)
    });
    phase("GPU export returned");
    result
}

fn run_gpu(gpu: &Gpu, request: &ExportRequest<'_>) -> ExportedVolume {
    run_gpu_with(gpu, request, &mut no_progress()).expect("GPU export")
}

fn run_cpu(request: &ExportRequest<'_>) -> ExportedVolume {
    phase("CPU export");
    export_cpu(request, &mut no_progress()).expect("CPU export")
}

// ---------------------------------------------------------------------------------------------------------------

#[test]
fn identity_is_bit_identical_for_every_type_kernel_and_path() {
    hang_guard("identity_is_bit_identical_for_every_type_kernel_and_path", || {
        let gpu = gpu();
        let dims = [13, 11, 9];
        let lps_from_index = oblique_grid([0.7, 0.9, 1.3], [-31.2, 17.9, 104.3], 0.3, -0.2);
        let target = TargetGrid { dims, lps_from_index };
        let zero_texels = vec![0.0f32; 4 * 5 * 4 * 3];
        let control =
            ControlDesc { dims: [5, 4, 3], texels: &zero_texels, box_min_ref: [-50.0; 3], box_max_ref: [150.0; 3] };
        let no_weights = vec![[0.0; 3]; 2];
        let tps = TpsDesc {
            centres_ref: &[[-30.0, 20.0, 100.0], [-20.0, 10.0, 110.0]],
            weights: &no_weights,
            linear: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            translation: [0.0; 3],
        };
        let len = dims.iter().product();
        for (f32_exact, paths) in [(false, 1), (true, 2)] {
            for expected in samples_of_every_type(len, f32_exact) {
                let source = SourceVolume { dims, samples: expected.as_borrowed(), lps_from_index };
                for pullback in [PullBack::Identity, PullBack::Control(control), PullBack::Tps(tps)] {
                    for kernel in KERNELS {
                        let request =
                            ExportRequest { interpolation: kernel, ..ExportRequest::new(source, target, pullback) };
                        let what = format!("{:?} {kernel:?} {pullback:?}", expected.sample_type());
                        assert_eq!(run_cpu(&request).samples, expected, "CPU {what}");
                        if paths == 2
                            && let Some(gpu) = &gpu
                        {
                            assert_eq!(run_gpu(gpu, &request).samples, expected, "GPU {what}");
                        }
                    }
                }
            }
        }
    });
}

/// `values` as samples of `like`'s type: rounded half to even and clamped to the type's range for integers, rounded
/// to f32 for f32 (the stated output rule, written here from the definition).
fn as_type_of(like: &ExportedSamples, values: &[f64]) -> ExportedSamples {
    macro_rules! integers {
        ($variant:ident, $t:ty) => {
            ExportedSamples::$variant(
                values.iter().map(|&v| v.round_ties_even().clamp(<$t>::MIN as f64, <$t>::MAX as f64) as $t).collect(),
            )
        };
    }
    match like {
        ExportedSamples::U8(_) => integers!(U8, u8),
        ExportedSamples::I8(_) => integers!(I8, i8),
        ExportedSamples::U16(_) => integers!(U16, u16),
        ExportedSamples::I16(_) => integers!(I16, i16),
        ExportedSamples::U32(_) => integers!(U32, u32),
        ExportedSamples::I32(_) => integers!(I32, i32),
        ExportedSamples::F32(_) => ExportedSamples::F32(values.iter().map(|&v| v as f32).collect()),
        ExportedSamples::F64(_) => ExportedSamples::F64(values.to_vec()),
    }
}

#[test]
fn whole_voxel_translations_are_exact_shifts() {
    hang_guard("whole_voxel_translations_are_exact_shifts", || {
        let gpu = gpu();
        let dims = [12, 10, 8];
        let spacing = [0.5, 0.25, 2.0];
        let lps_from_index = axis_grid(spacing, [-3.0, 4.0, 10.0]);
        let shift_vox = [5i64, -3, 1];
        let b_mm: [f64; 3] = std::array::from_fn(|a| shift_vox[a] as f64 * spacing[a]);
        let target = TargetGrid { dims, lps_from_index };
        let tps = TpsDesc {
            centres_ref: &[[0.0, 5.0, 12.0]],
            weights: &[[0.0; 3]],
            linear: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            translation: b_mm,
        };
        let texels: Vec<f32> =
            (0..4 * 4 * 4).flat_map(|_| [b_mm[0] as f32, b_mm[1] as f32, b_mm[2] as f32, 0.0]).collect();
        let control = ControlDesc { dims: [4, 4, 4], texels: &texels, box_min_ref: [-5.0; 3], box_max_ref: [30.0; 3] };
        let outside = -1024.0;
        let idx = |q: [i64; 3]| (q[0] + dims[0] as i64 * (q[1] + dims[1] as i64 * q[2])) as usize;
        // Every sample type, each uploaded in its own type on the GPU and stored in it (or in f32).
        for samples in samples_of_every_type(dims.iter().product(), true) {
            let source = SourceVolume { dims, samples: samples.as_borrowed(), lps_from_index };
            let mut shifted = Vec::new();
            for k in 0..dims[2] as i64 {
                for j in 0..dims[1] as i64 {
                    for i in 0..dims[0] as i64 {
                        let q = [i + shift_vox[0], j + shift_vox[1], k + shift_vox[2]];
                        let inside = (0..3).all(|a| (0..dims[a] as i64).contains(&q[a]));
                        shifted.push(if inside { samples.get_f64(idx(q)) } else { outside });
                    }
                }
            }
            let expected_f32 = ExportedSamples::F32(shifted.iter().map(|&v| v as f32).collect());
            let expected_source = as_type_of(&samples, &shifted);
            for pullback in [PullBack::Tps(tps), PullBack::Control(control)] {
                for kernel in KERNELS {
                    let request = ExportRequest {
                        interpolation: kernel,
                        output: OutputType::F32,
                        outside_value: outside,
                        ..ExportRequest::new(source, target, pullback)
                    };
                    let as_source = ExportRequest { output: OutputType::Source, ..request };
                    let what = format!("{:?} {kernel:?} {pullback:?}", samples.sample_type());
                    assert_eq!(run_cpu(&request).samples, expected_f32, "CPU f32 {what}");
                    assert_eq!(run_cpu(&as_source).samples, expected_source, "CPU {what}");
                    if let Some(gpu) = &gpu {
                        assert_eq!(run_gpu(gpu, &request).samples, expected_f32, "GPU f32 {what}");
                        assert_eq!(run_gpu(gpu, &as_source).samples, expected_source, "GPU {what}");
                    }
                }
            }
        }
    });
}

#[test]
fn outside_values_are_rounded_and_clamped_into_every_type() {
    hang_guard("outside_values_are_rounded_and_clamped_into_every_type", || {
        let gpu = gpu();
        // A target 100 mm away from the source: every voxel is outside, so every output is the outside value as the
        // output type stores it (the GPU takes it from the host's conversion, which must be the CPU path's).
        let source_dims = [2, 2, 2];
        let target = TargetGrid { dims: [3, 2, 2], lps_from_index: axis_grid([1.0; 3], [100.0, 0.0, 0.0]) };
        let values = [-1e10, -129.5, -2.5, -0.5, 0.5, 2.5, 3.5, 255.5, 32_767.5, 65_535.5, 4_294_967_294.5, 1e10];
        for samples in samples_of_every_type(8, true) {
            let source = SourceVolume {
                dims: source_dims,
                samples: samples.as_borrowed(),
                lps_from_index: axis_grid([1.0; 3], [0.0; 3]),
            };
            for outside in values {
                for output in [OutputType::Source, OutputType::F32] {
                    let request = ExportRequest {
                        interpolation: Interpolation::Nearest,
                        output,
                        outside_value: outside,
                        ..ExportRequest::new(source, target, PullBack::Identity)
                    };
                    let like = if output == OutputType::F32 { &ExportedSamples::F32(Vec::new()) } else { &samples };
                    let expected = as_type_of(like, &[outside; 12]);
                    let what = format!("{:?} {output:?}, outside {outside}", samples.sample_type());
                    assert_eq!(run_cpu(&request).samples, expected, "CPU {what}");
                    let Some(gpu) = &gpu else { continue };
                    let f64_inexact = expected.sample_type() == warpbench_gpu::SampleType::F64
                        && f64::from(outside as f32) != outside;
                    if f64_inexact {
                        // The GPU stores f64 outputs as f32: an outside value that f32 does not hold goes to the CPU.
                        let err = run_gpu_with(gpu, &request, &mut no_progress()).expect_err(&what);
                        assert!(matches!(err, GpuError::Unsupported(ref m) if m.contains("export_cpu")), "{err}");
                    } else {
                        assert_eq!(run_gpu(gpu, &request).samples, expected, "GPU {what}");
                    }
                }
            }
        }
    });
}

/// A CT-like source on an oblique grid and a target grid that differs in size, spacing and orientation.
struct Scene {
    ct: Vec<i16>,
    source_dims: [usize; 3],
    source_lps_from_index: [[f64; 4]; 4],
    target: TargetGrid,
    tps: Tps,
}

impl Scene {
    fn new() -> Self {
        let n = 40;
        Self {
            ct: common::ct_phantom(n),
            source_dims: [n; 3],
            source_lps_from_index: oblique_grid([2.0, 2.0, 2.0], [-38.0, -41.0, -40.0], 0.1, 0.05),
            target: TargetGrid {
                dims: [44, 38, 36],
                lps_from_index: oblique_grid([1.8, 2.1, 2.2], [-39.0, -37.0, -38.0], -0.05, 0.0),
            },
            tps: Tps::new(),
        }
    }

    fn source(&self) -> SourceVolume<'_> {
        SourceVolume {
            dims: self.source_dims,
            samples: ExportSamples::I16(&self.ct),
            lps_from_index: self.source_lps_from_index,
        }
    }
}

/// Compares `got` with `reference` (both F32 outputs of `request`) voxel by voxel, skipping voxels whose oracle
/// position is within `POSITION_TOLERANCE_VOX` of a decision (fewer than 1 % may be); returns the voxels skipped.
fn compare(request: &ExportRequest<'_>, got: &ExportedSamples, reference: &[f64], tolerance: f64, what: &str) -> usize {
    let [nx, ny, nz] = request.target.dims;
    let (mut worst, mut skipped) = (0.0f64, 0);
    for k in 0..nz {
        for j in 0..ny {
            for i in 0..nx {
                let idx = i + nx * (j + ny * k);
                let s = source_index_f64(request, [i, j, k]);
                if near_a_decision(s, request.source.dims, request.interpolation) {
                    skipped += 1;
                    continue;
                }
                let diff = (got.get_f64(idx) - reference[idx]).abs();
                assert!(diff <= tolerance, "{what}: voxel ({i}, {j}, {k}) differs by {diff} > {tolerance}");
                worst = worst.max(diff);
            }
        }
    }
    eprintln!("{what}: worst difference {worst:.3e} (tolerance {tolerance:.3e}), {skipped} voxels skipped");
    assert!(skipped * 100 < nx * ny * nz, "{what}: {skipped} voxels near a decision");
    skipped
}

#[test]
fn gpu_matches_cpu_and_both_match_the_f64_oracle() {
    hang_guard("gpu_matches_cpu_and_both_match_the_f64_oracle", || {
        let gpu = gpu();
        let scene = Scene::new();
        let source = scene.source();
        let tps = scene.tps.desc();
        let (lo, hi) = ([-45.0; 3], [45.0; 3]);
        let texels = control_texels(&tps, 24, lo, hi);
        let control = ControlDesc { dims: [24; 3], texels: &texels, box_min_ref: lo, box_max_ref: hi };
        let samples = ExportedSamples::I16(scene.ct.clone());
        let tolerance = value_tolerance(&samples, scene.source_dims);
        let outside = -4000.0; // not a value of the phantom (air is −1000)
        for pullback in [PullBack::Tps(tps), PullBack::Control(control)] {
            for kernel in KERNELS {
                let request = ExportRequest {
                    interpolation: kernel,
                    output: OutputType::F32,
                    outside_value: outside,
                    ..ExportRequest::new(source, scene.target, pullback)
                };
                let name = if matches!(pullback, PullBack::Tps(_)) { "TPS" } else { "control" };
                let [nx, ny, nz] = scene.target.dims;
                let mut oracle = Vec::with_capacity(nx * ny * nz);
                for k in 0..nz {
                    for j in 0..ny {
                        for i in 0..nx {
                            let s = source_index_f64(&request, [i, j, k]);
                            oracle.push(value_f64(&samples, scene.source_dims, s, kernel).unwrap_or(outside));
                        }
                    }
                }
                let cpu = run_cpu(&request);
                // The pull-back moves voxels in and out of the source: both kinds must be present.
                let outside_count = (0..oracle.len()).filter(|&i| oracle[i] == outside).count();
                assert!(outside_count > 100 && outside_count < oracle.len() / 2, "{outside_count} outside");
                compare(&request, &cpu.samples, &oracle, tolerance, &format!("CPU vs oracle, {name} {kernel:?}"));
                let i16_request = ExportRequest { output: OutputType::Source, ..request };
                let cpu_i16 = run_cpu(&i16_request);
                if let Some(gpu) = &gpu {
                    let on_gpu = run_gpu(gpu, &request);
                    compare(
                        &request,
                        &on_gpu.samples,
                        &oracle,
                        tolerance,
                        &format!("GPU vs oracle, {name} {kernel:?}"),
                    );
                    let cpu_values: Vec<f64> = (0..cpu.samples.len()).map(|i| cpu.samples.get_f64(i)).collect();
                    compare(
                        &request,
                        &on_gpu.samples,
                        &cpu_values,
                        tolerance,
                        &format!("GPU vs CPU, {name} {kernel:?}"),
                    );
                    // Rounded outputs differ by at most one more unit (a value near a half may round either way).
                    let gpu_i16 = run_gpu(gpu, &i16_request);
                    let cpu_i16: Vec<f64> = (0..cpu_i16.samples.len()).map(|i| cpu_i16.samples.get_f64(i)).collect();
                    compare(&request, &gpu_i16.samples, &cpu_i16, tolerance + 1.0, &format!("GPU vs CPU i16, {name}"));
                }
            }
        }
    });
}

/// One export path, as the slab test runs both.
type Runner<'a> =
    Box<dyn Fn(&ExportRequest<'_>, &mut dyn FnMut(Progress) -> bool) -> Result<ExportedVolume, GpuError> + 'a>;

#[test]
fn slabs_progress_and_cancellation() {
    hang_guard("slabs_progress_and_cancellation", || {
        let gpu = gpu();
        let scene = Scene::new();
        let tps = scene.tps.desc();
        let base = ExportRequest {
            interpolation: Interpolation::CatmullRom,
            ..ExportRequest::new(scene.source(), scene.target, PullBack::Tps(tps))
        };
        let nz = scene.target.dims[2];
        let mut runners: Vec<(&str, Runner<'_>)> = vec![("CPU", Box::new(|r, p| export_cpu(r, p)))];
        if let Some(gpu) = &gpu {
            runners.push(("GPU", Box::new(move |r, p| run_gpu_with(gpu, r, p))));
        }
        for (name, run) in &runners {
            let whole = run(&ExportRequest { slab_slices: Some(nz), ..base }, &mut no_progress()).expect("one slab");
            for slab in [1, 5] {
                let mut calls = Vec::new();
                let request = ExportRequest { slab_slices: Some(slab), ..base };
                let result = run(&request, &mut |p| {
                    calls.push(p);
                    true
                })
                .expect("slabs");
                assert_eq!(result, whole, "{name}: {slab}-slice slabs differ from one slab");
                let done: Vec<usize> = calls.iter().map(|p| p.slices_done).collect();
                let expected: Vec<usize> = (1..=nz.div_ceil(slab)).map(|s| (s * slab).min(nz)).collect();
                assert_eq!(done, expected, "{name}: progress");
                assert!(calls.iter().all(|p| p.slices_total == nz));
            }
            let mut calls = 0;
            let cancelled = run(&ExportRequest { slab_slices: Some(4), ..base }, &mut |_| {
                calls += 1;
                calls < 2
            });
            match cancelled {
                Err(GpuError::Cancelled { slices_done: 8, slices_total }) => assert_eq!(slices_total, nz),
                other => panic!("{name}: expected a cancellation after 8 slices, got {other:?}"),
            }
            assert_eq!(calls, 2, "{name}: no progress call after the cancellation");
        }
        // A 512 × 512 × 1000 CT target is split into slabs that each fit one binding and the budget, in the bytes the
        // output stores (2 per i16 voxel, 4 per f32), and whose TPS work fits the work budget.
        if let Some(Gpu(ctx, _)) = &gpu {
            let big = TargetGrid { dims: [512, 512, 1000], ..scene.target };
            let cap = ctx.limits.max_storage_buffer_binding_size.min(ExportPass::SLAB_BUDGET_BYTES);
            for (output, bytes_per_voxel) in [(OutputType::Source, 2), (OutputType::F32, 4)] {
                for pullback in [PullBack::Identity, PullBack::Tps(tps)] {
                    let request =
                        ExportRequest { target: big, output, ..ExportRequest::new(scene.source(), big, pullback) };
                    let slab = ExportPass::slab_slices(ctx, &request).expect("slabs for a large CT");
                    assert!((1..1000).contains(&slab), "{slab}");
                    assert!((slab * 512 * 512 * bytes_per_voxel) as u64 <= cap, "{output:?}: {slab} slices");
                    let centres = if matches!(pullback, PullBack::Tps(_)) { tps.centres_ref.len() } else { 0 };
                    assert!((slab * 512 * 512 * (1 + centres)) as u64 <= ExportPass::WORK_BUDGET, "{slab} slices");
                    let three = ExportRequest { slab_slices: Some(3), ..request };
                    assert_eq!(ExportPass::slab_slices(ctx, &three).expect("slabs"), 3);
                }
            }
        }
    });
}

#[test]
fn cubic_overshoot_is_clamped_and_ties_round_to_even() {
    hang_guard("cubic_overshoot_is_clamped_and_ties_round_to_even", || {
        let gpu = gpu();
        // A step 0 → 255 along x sampled halfway between voxels: Catmull-Rom undershoots to −255/16 before it and
        // overshoots to 255·17/16 after it.
        let dims = [8, 1, 1];
        let step: Vec<u8> = vec![0, 0, 0, 0, 255, 255, 255, 255];
        let half_shifted = TargetGrid { dims: [7, 1, 1], lps_from_index: axis_grid([1.0; 3], [0.5, 0.0, 0.0]) };
        let source =
            SourceVolume { dims, samples: ExportSamples::U8(&step), lps_from_index: axis_grid([1.0; 3], [0.0; 3]) };
        let cubic = ExportRequest {
            interpolation: Interpolation::CatmullRom,
            output: OutputType::F32,
            ..ExportRequest::new(source, half_shifted, PullBack::Identity)
        };
        let f = run_cpu(&cubic).samples;
        assert_eq!(f, ExportedSamples::F32(vec![0.0, 0.0, -15.9375, 127.5, 270.9375, 255.0, 255.0]));
        let u8_out = ExportRequest { output: OutputType::Source, ..cubic };
        let expected = ExportedSamples::U8(vec![0, 0, 0, 128, 255, 255, 255]);
        assert_eq!(run_cpu(&u8_out).samples, expected);
        // i16 at the ends of its range.
        let wide: Vec<i16> = vec![i16::MIN, i16::MIN, i16::MIN, i16::MIN, i16::MAX, i16::MAX, i16::MAX, i16::MAX];
        let i16_out = ExportRequest {
            source: SourceVolume { samples: ExportSamples::I16(&wide), ..source },
            output: OutputType::Source,
            ..cubic
        };
        let expected_i16 = ExportedSamples::I16(vec![i16::MIN, i16::MIN, i16::MIN, 0, i16::MAX, i16::MAX, i16::MAX]);
        assert_eq!(run_cpu(&i16_out).samples, expected_i16);
        // Ties: trilinear halfway between 2 and 3 is 2.5 → 2, between 3 and 4 is 3.5 → 4, between 4 and 5 is 4.5 → 4.
        let ramp: Vec<u8> = vec![2, 3, 4, 5, 6, 7, 8, 9];
        let ties = ExportRequest {
            source: SourceVolume { samples: ExportSamples::U8(&ramp), ..source },
            interpolation: Interpolation::Trilinear,
            output: OutputType::Source,
            ..cubic
        };
        let expected_ties = ExportedSamples::U8(vec![2, 4, 4, 6, 6, 8, 8]);
        assert_eq!(run_cpu(&ties).samples, expected_ties);
        if let Some(gpu) = &gpu {
            assert_eq!(run_gpu(gpu, &u8_out).samples, expected);
            assert_eq!(run_gpu(gpu, &i16_out).samples, expected_i16);
            assert_eq!(run_gpu(gpu, &ties).samples, expected_ties);
        }
    });
}

#[test]
fn bad_input_is_an_error_not_a_panic() {
    hang_guard("bad_input_is_an_error_not_a_panic", || {
        let gpu = gpu();
        let samples = vec![0i16; 4 * 4 * 4];
        let grid = axis_grid([1.0; 3], [0.0; 3]);
        let source = SourceVolume { dims: [4, 4, 4], samples: ExportSamples::I16(&samples), lps_from_index: grid };
        let target = TargetGrid { dims: [4, 4, 4], lps_from_index: grid };
        let ok = ExportRequest::new(source, target, PullBack::Identity);
        let mut singular = grid;
        singular[2] = [0.0, 0.0, 0.0, 5.0];
        let mut nan = grid;
        nan[1][3] = f64::NAN;
        let mut projective = grid;
        projective[3] = [0.0, 0.0, 0.1, 1.0];
        let short_texels = vec![0.0f32; 4 * 7];
        let bad_weight = [[0.0, f64::INFINITY, 0.0]];
        let identity3 = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        let cases: Vec<(&str, ExportRequest<'_>)> = vec![
            (
                "short samples",
                ExportRequest { source: SourceVolume { samples: ExportSamples::I16(&samples[1..]), ..source }, ..ok },
            ),
            ("zero dims", ExportRequest { target: TargetGrid { dims: [4, 0, 4], ..target }, ..ok }),
            ("absurd dims", ExportRequest { target: TargetGrid { dims: [1 << 21, 1, 1], ..target }, ..ok }),
            ("too large", ExportRequest { target: TargetGrid { dims: [1 << 20, 1 << 20, 1 << 20], ..target }, ..ok }),
            ("over budget", ExportRequest { max_output_bytes: 100, ..ok }),
            ("singular source", ExportRequest { source: SourceVolume { lps_from_index: singular, ..source }, ..ok }),
            ("NaN target", ExportRequest { target: TargetGrid { lps_from_index: nan, ..target }, ..ok }),
            ("projective", ExportRequest { target: TargetGrid { lps_from_index: projective, ..target }, ..ok }),
            ("NaN outside for i16", ExportRequest { outside_value: f64::NAN, ..ok }),
            ("zero slab", ExportRequest { slab_slices: Some(0), ..ok }),
            (
                "short control",
                ExportRequest {
                    pullback: PullBack::Control(ControlDesc {
                        dims: [2, 2, 2],
                        texels: &short_texels,
                        box_min_ref: [0.0; 3],
                        box_max_ref: [1.0; 3],
                    }),
                    ..ok
                },
            ),
            (
                "infinite TPS weight",
                ExportRequest {
                    pullback: PullBack::Tps(TpsDesc {
                        centres_ref: &[[0.0; 3]],
                        weights: &bad_weight,
                        linear: identity3,
                        translation: [0.0; 3],
                    }),
                    ..ok
                },
            ),
        ];
        for (what, request) in &cases {
            let err = export_cpu(request, &mut no_progress()).expect_err(what);
            assert!(matches!(err, GpuError::InvalidInput(_)), "{what}: {err}");
            if let Some(gpu) = &gpu {
                let err = run_gpu_with(gpu, request, &mut no_progress()).expect_err(what);
                assert!(matches!(err, GpuError::InvalidInput(_)), "GPU {what}: {err}");
            }
        }
        // NaN outside values are fine for float outputs.
        let nan_f32 = ExportRequest { outside_value: f64::NAN, output: OutputType::F32, ..ok };
        assert!(export_cpu(&nan_f32, &mut no_progress()).is_ok());
        // Samples that f32 does not hold exactly go to the CPU path.
        let wide = vec![(1 << 24) + 1; 64];
        let fractions = vec![0.1f64; 64];
        for samples in [ExportSamples::I32(&wide), ExportSamples::F64(&fractions)] {
            let request = ExportRequest { source: SourceVolume { samples, ..source }, ..ok };
            let cpu = export_cpu(&request, &mut no_progress()).expect("the CPU path is exact");
            assert_eq!(cpu.samples.as_borrowed().len(), 64);
            assert_eq!(cpu.samples.get_f64(21), samples_get(samples, 21));
            if let Some(gpu) = &gpu {
                let err = run_gpu_with(gpu, &request, &mut no_progress()).expect_err("not exact in f32");
                assert!(matches!(err, GpuError::Unsupported(ref m) if m.contains("export_cpu")), "{err}");
            }
        }
        assert_eq!(std::mem::size_of::<ExportUniforms>(), 304);
    });
}

fn samples_get(samples: ExportSamples<'_>, i: usize) -> f64 {
    match samples {
        ExportSamples::I32(v) => f64::from(v[i]),
        ExportSamples::F64(v) => v[i],
        _ => unreachable!("only used for I32 and F64"),
    }
}

#[test]
fn nearest_and_outside_follow_the_stated_rules() {
    hang_guard("nearest_and_outside_follow_the_stated_rules", || {
        // Source index s = target index − 0.5 + 0.25·k along x: the inside test is −½ ≤ s ≤ n − ½ inclusive, and nearest
        // takes ⌊s + ½⌋.
        let dims = [4, 1, 1];
        let values: Vec<f32> = vec![10.0, 20.0, 30.0, 40.0];
        let source =
            SourceVolume { dims, samples: ExportSamples::F32(&values), lps_from_index: axis_grid([1.0; 3], [0.0; 3]) };
        let target = TargetGrid { dims: [20, 1, 1], lps_from_index: axis_grid([0.25, 1.0, 1.0], [-1.0, 0.0, 0.0]) };
        let request = ExportRequest {
            interpolation: Interpolation::Nearest,
            outside_value: -1.0,
            ..ExportRequest::new(source, target, PullBack::Identity)
        };
        let got = run_cpu(&request).samples;
        let expected: Vec<f32> = (0..20)
            .map(|i| {
                let s = -1.0 + 0.25 * f64::from(i);
                if (-0.5..=3.5).contains(&s) { values[((s + 0.5).floor() as usize).min(3)] } else { -1.0 }
            })
            .collect();
        assert_eq!(got, ExportedSamples::F32(expected.clone()));
        assert_eq!(got.get_f64(2), 10.0, "s = −½ is inside");
        assert_eq!(got.get_f64(18), 40.0, "s = n − ½ is inside");
        assert_eq!(got.get_f64(19), -1.0, "s = n − ¼ is outside");
        if let Some(gpu) = &gpu() {
            assert_eq!(run_gpu(gpu, &request).samples, ExportedSamples::F32(expected));
        }
    });
}

/// One thread's share of [`exports_never_hang_with_shared_devices_slabs_in_flight_and_cancellations`]: for a packed
/// 16-bit, a packed 8-bit and an f32 output, the export in one slab, then in slabs of 1, 2, 3 and 5 slices (each
/// equal to the one-slab export bit for bit, with one progress call per slab), then cancelled after the first,
/// second and last-but-one slab.
fn export_every_way(gpu: &Gpu, scene: &Scene, mr: &[u8]) {
    let tps = scene.tps.desc();
    let ct = scene.source();
    let mr = SourceVolume { samples: ExportSamples::U8(mr), ..ct };
    let nz = scene.target.dims[2];
    for (source, output) in [(ct, OutputType::Source), (mr, OutputType::Source), (ct, OutputType::F32)] {
        let base = ExportRequest { output, ..ExportRequest::new(source, scene.target, PullBack::Tps(tps)) };
        let whole = run_gpu(gpu, &ExportRequest { slab_slices: Some(nz), ..base });
        for slab in [1, 2, 3, 5] {
            let request = ExportRequest { slab_slices: Some(slab), ..base };
            let mut calls = 0;
            let sliced = run_gpu_with(gpu, &request, &mut |_| {
                calls += 1;
                true
            })
            .expect("slabs");
            assert_eq!(sliced, whole, "{output:?}: {slab}-slice slabs differ from one slab");
            assert_eq!(calls, nz.div_ceil(slab), "{output:?}: progress calls with {slab}-slice slabs");
            for stop_after in [1, 2, nz.div_ceil(slab) - 1] {
                let mut calls = 0;
                let cancelled = run_gpu_with(gpu, &request, &mut |_| {
                    calls += 1;
                    calls < stop_after
                });
                let done = (stop_after * slab).min(nz);
                assert!(
                    matches!(cancelled, Err(GpuError::Cancelled { slices_done, .. }) if slices_done == done),
                    "{output:?}, {slab}-slice slabs: expected a cancellation after {done} slices, got {cancelled:?}"
                );
            }
        }
    }
}

/// Issue 28: on an NVIDIA H200 shared by every GPU test binary, two tests of this file stalled for over a minute
/// (not reproduced on lavapipe). Every wait of the GPU path is a poll with a deadline; this runs exports in the ways
/// a wait could miss its wake-up or never end: three threads on one shared device and pass (one thread's poll
/// answers another's map callback), a fourth thread that polls that device all along, a fifth on a device of its
/// own, many slabs in flight, and cancellations that leave slabs queued. Under the hang guard; afterwards the
/// shared device reports no error (nothing was left mapped or unmapped twice) and exports again.
#[test]
fn exports_never_hang_with_shared_devices_slabs_in_flight_and_cancellations() {
    const TEST: &str = "exports_never_hang_with_shared_devices_slabs_in_flight_and_cancellations";
    hang_guard(TEST, || {
        let Some(shared) = gpu() else { return };
        let scene = Scene::new();
        let mr = common::mr_phantom(scene.source_dims[0]);
        let exporting = AtomicBool::new(true);
        thread::scope(|s| {
            let named = |name: &str| thread::Builder::new().name(format!("{TEST}/{name}"));
            let poller = named("poller")
                .spawn_scoped(s, || {
                    phase("polling the shared device");
                    while exporting.load(Ordering::Acquire) {
                        let _ = shared.0.device.poll(wgpu::PollType::Poll);
                        thread::sleep(Duration::from_micros(50));
                    }
                })
                .expect("spawn");
            let mut exporters: Vec<_> = (0..3)
                .map(|i| {
                    named(&format!("shared {i}"))
                        .spawn_scoped(s, || export_every_way(&shared, &scene, &mr))
                        .expect("spawn")
                })
                .collect();
            let own = named("own device").spawn_scoped(s, || {
                let own = gpu().expect("a second device");
                export_every_way(&own, &scene, &mr);
            });
            exporters.push(own.expect("spawn"));
            let results: Vec<_> = exporters.into_iter().map(thread::ScopedJoinHandle::join).collect();
            exporting.store(false, Ordering::Release);
            poller.join().expect("poller");
            for result in results {
                if let Err(panic) = result {
                    std::panic::resume_unwind(panic);
                }
            }
        });
        assert_eq!(shared.0.take_errors(), Vec::<String>::new(), "the shared device reported errors");
        let again = run_gpu(&shared, &ExportRequest::new(scene.source(), scene.target, PullBack::Identity));
        assert_eq!(again.samples.len(), scene.target.dims.iter().product::<usize>());
    });
}
