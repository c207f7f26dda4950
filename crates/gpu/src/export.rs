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
//! even** (IEEE 754's default, WGSL's `round`, numpy's `rint`) and clamped to the type's range. Non-finite outside
//! values are refused for integer outputs.
//!
//! # Slabs and limits
//!
//! The target is processed in z-slabs ([`ExportRequest::slab_slices`], or automatic), and the progress callback is
//! called after each slab with the slices done so far; returning `false` cancels with [`GpuError::Cancelled`]. On the
//! GPU each slab's f32 output buffer fits `max_storage_buffer_binding_size` and [`ExportPass::SLAB_BUDGET_BYTES`], so
//! outputs much larger than one binding (a 512 × 512 × 1000 CT) work; one target slice must fit (4096 × 4096 does).
//! The source is one `R32Float` 3-D texture: at most `max_texture_dimension_3d` (usually 2048) per axis and
//! [`ExportPass::MAX_SOURCE_BYTES`]; larger sources are a [`GpuError::Unsupported`] error naming the CPU path, which
//! has no such limit. Outputs beyond
//! [`ExportRequest::max_output_bytes`] (default [`DEFAULT_MAX_OUTPUT_BYTES`], 16 GiB) are refused before anything is
//! allocated.

mod cpu;
mod gpu;

use glam::{DMat3, DMat4, DVec3, DVec4};

use crate::control::{ControlDesc, PreparedControl};
use crate::error::{GpuError, Result};
use crate::pullback::{TpsDesc, TpsLocal};

pub use cpu::export_cpu;
pub use gpu::{ExportPass, ExportUniforms};

/// Outputs larger than this many bytes are refused unless [`ExportRequest::max_output_bytes`] says otherwise.
pub const DEFAULT_MAX_OUTPUT_BYTES: u64 = 16 << 30;
/// Largest accepted size of any grid axis.
pub const MAX_DIMENSION: usize = 1 << 20;

/// The sample types of the export's input and output.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SampleType {
    U8,
    I8,
    U16,
    I16,
    U32,
    I32,
    F32,
    F64,
}

impl SampleType {
    #[must_use]
    pub fn bytes(self) -> u64 {
        match self {
            Self::U8 | Self::I8 => 1,
            Self::U16 | Self::I16 => 2,
            Self::U32 | Self::I32 | Self::F32 => 4,
            Self::F64 => 8,
        }
    }

    #[must_use]
    pub fn is_integer(self) -> bool {
        !matches!(self, Self::F32 | Self::F64)
    }
}

/// Borrowed source samples, x fastest.
#[derive(Clone, Copy, Debug)]
pub enum ExportSamples<'a> {
    U8(&'a [u8]),
    I8(&'a [i8]),
    U16(&'a [u16]),
    I16(&'a [i16]),
    U32(&'a [u32]),
    I32(&'a [i32]),
    F32(&'a [f32]),
    F64(&'a [f64]),
}

impl ExportSamples<'_> {
    #[must_use]
    pub fn len(&self) -> usize {
        match self {
            Self::U8(v) => v.len(),
            Self::I8(v) => v.len(),
            Self::U16(v) => v.len(),
            Self::I16(v) => v.len(),
            Self::U32(v) => v.len(),
            Self::I32(v) => v.len(),
            Self::F32(v) => v.len(),
            Self::F64(v) => v.len(),
        }
    }

    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    #[must_use]
    pub fn sample_type(&self) -> SampleType {
        match self {
            Self::U8(_) => SampleType::U8,
            Self::I8(_) => SampleType::I8,
            Self::U16(_) => SampleType::U16,
            Self::I16(_) => SampleType::I16,
            Self::U32(_) => SampleType::U32,
            Self::I32(_) => SampleType::I32,
            Self::F32(_) => SampleType::F32,
            Self::F64(_) => SampleType::F64,
        }
    }

    /// Whether every sample is exactly an f32 (always for 8- and 16-bit integers and f32; for u32 and i32 when every
    /// |v| ≤ 2²⁴; for f64 when every value survives the round trip, NaN included). The GPU path needs this.
    #[must_use]
    pub fn exact_in_f32(&self) -> bool {
        const LIMIT: i64 = 1 << 24;
        match self {
            Self::U8(_) | Self::I8(_) | Self::U16(_) | Self::I16(_) | Self::F32(_) => true,
            Self::U32(v) => v.iter().all(|&x| i64::from(x) <= LIMIT),
            Self::I32(v) => v.iter().all(|&x| i64::from(x).abs() <= LIMIT),
            Self::F64(v) => v.iter().all(|&x| x.is_nan() || f64::from(x as f32).to_bits() == x.to_bits()),
        }
    }
}

/// Owned output samples, x fastest.
#[derive(Clone, Debug, PartialEq)]
pub enum ExportedSamples {
    U8(Vec<u8>),
    I8(Vec<i8>),
    U16(Vec<u16>),
    I16(Vec<i16>),
    U32(Vec<u32>),
    I32(Vec<i32>),
    F32(Vec<f32>),
    F64(Vec<f64>),
}

impl ExportedSamples {
    #[must_use]
    pub fn len(&self) -> usize {
        self.as_borrowed().len()
    }

    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    #[must_use]
    pub fn sample_type(&self) -> SampleType {
        self.as_borrowed().sample_type()
    }

    /// The samples as a borrowed slice (for example, to export them again).
    #[must_use]
    pub fn as_borrowed(&self) -> ExportSamples<'_> {
        match self {
            Self::U8(v) => ExportSamples::U8(v),
            Self::I8(v) => ExportSamples::I8(v),
            Self::U16(v) => ExportSamples::U16(v),
            Self::I16(v) => ExportSamples::I16(v),
            Self::U32(v) => ExportSamples::U32(v),
            Self::I32(v) => ExportSamples::I32(v),
            Self::F32(v) => ExportSamples::F32(v),
            Self::F64(v) => ExportSamples::F64(v),
        }
    }

    /// Sample `i` as f64 (exact for every type).
    #[must_use]
    pub fn get_f64(&self, i: usize) -> f64 {
        match self {
            Self::U8(v) => f64::from(v[i]),
            Self::I8(v) => f64::from(v[i]),
            Self::U16(v) => f64::from(v[i]),
            Self::I16(v) => f64::from(v[i]),
            Self::U32(v) => f64::from(v[i]),
            Self::I32(v) => f64::from(v[i]),
            Self::F32(v) => f64::from(v[i]),
            Self::F64(v) => v[i],
        }
    }
}

/// The moving volume: dims, samples (x fastest) and the row-major 4×4 `lps_from_index` (0 = centre of the first
/// voxel), in moving LPS mm.
#[derive(Clone, Copy, Debug)]
pub struct SourceVolume<'a> {
    pub dims: [usize; 3],
    pub samples: ExportSamples<'a>,
    pub lps_from_index: [[f64; 4]; 4],
}

/// The output grid: dims and the row-major 4×4 `lps_from_index` into ref space (the fixed volume's LPS, usually
/// the fixed volume's own grid).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TargetGrid {
    pub dims: [usize; 3],
    pub lps_from_index: [[f64; 4]; 4],
}

/// The pull-back u: ref mm → moving LPS mm.
#[derive(Clone, Copy, Debug)]
pub enum PullBack<'a> {
    /// u(x) = x: the two spaces coincide (resampling only).
    Identity,
    /// A sampled pull-back (the renderer's control texture): u(x) = x + trilinear lookup of the texels.
    Control(ControlDesc<'a>),
    /// The exact TPS, evaluated per voxel.
    Tps(TpsDesc<'a>),
}

/// How the source is sampled at non-integer positions (clamp-to-edge taps on every kernel).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Interpolation {
    /// The voxel whose centre is nearest: ⌊s + ½⌋.
    Nearest,
    /// Trilinear, 8 taps.
    #[default]
    Trilinear,
    /// Catmull-Rom cubic convolution (interpolating, no prefilter), 64 taps (module docs).
    CatmullRom,
}

/// The output's sample type.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum OutputType {
    /// The source's sample type: rounded half to even and clamped to the type's range.
    #[default]
    Source,
    /// f32, unrounded.
    F32,
}

/// Progress of an export: slices of the target finished so far, out of the total.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Progress {
    pub slices_done: usize,
    pub slices_total: usize,
}

/// Everything an export needs, shared by [`export_cpu`] and [`ExportPass::run`].
#[derive(Clone, Copy, Debug)]
pub struct ExportRequest<'a> {
    pub source: SourceVolume<'a>,
    pub target: TargetGrid,
    pub pullback: PullBack<'a>,
    pub interpolation: Interpolation,
    pub output: OutputType,
    /// The value of target voxels whose source position is outside the source (module docs); must be finite for
    /// integer outputs, and is rounded and clamped like the samples.
    pub outside_value: f64,
    /// Slices per slab; `None` chooses (per path). Small values give more progress calls.
    pub slab_slices: Option<usize>,
    /// Refuse outputs larger than this.
    pub max_output_bytes: u64,
}

impl<'a> ExportRequest<'a> {
    /// A request with trilinear interpolation, the source's sample type, outside value 0 and automatic slabs.
    #[must_use]
    pub fn new(source: SourceVolume<'a>, target: TargetGrid, pullback: PullBack<'a>) -> Self {
        Self {
            source,
            target,
            pullback,
            interpolation: Interpolation::default(),
            output: OutputType::default(),
            outside_value: 0.0,
            slab_slices: None,
            max_output_bytes: DEFAULT_MAX_OUTPUT_BYTES,
        }
    }

    /// The output's sample type.
    #[must_use]
    pub fn output_type(&self) -> SampleType {
        match self.output {
            OutputType::Source => self.source.samples.sample_type(),
            OutputType::F32 => SampleType::F32,
        }
    }
}

/// The result: the target grid and its samples.
#[derive(Clone, Debug, PartialEq)]
pub struct ExportedVolume {
    pub dims: [usize; 3],
    /// The target grid's `lps_from_index` (ref = fixed LPS).
    pub lps_from_index: [[f64; 4]; 4],
    pub samples: ExportedSamples,
}

/// The pull-back's displacement as both paths evaluate it.
#[derive(Clone, Debug)]
pub(crate) enum PlanPullBack {
    Identity,
    Control { dims: [usize; 3], texels: Vec<[f32; 4]> },
    Tps(TpsLocal),
}

/// A checked request, reduced to the f32 numbers both paths use.
#[derive(Clone, Debug)]
pub(crate) struct Plan {
    pub target_dims: [usize; 3],
    pub source_dims: [usize; 3],
    /// Columns of the affine maps (module docs, step 1 and 2).
    pub source_index_from_target_index: [[f32; 4]; 4],
    pub pullback_from_target_index: [[f32; 4]; 4],
    pub source_index_from_lps: [[f32; 4]; 4],
    pub pullback: PlanPullBack,
    pub interpolation: Interpolation,
    pub output: SampleType,
    pub outside_value: f64,
    pub output_len: usize,
    pub slab_slices: Option<usize>,
}

fn invalid(message: String) -> GpuError {
    GpuError::InvalidInput(message)
}

/// Checks dims: every axis in 1..=[`MAX_DIMENSION`]; returns the voxel count.
fn check_dims(what: &str, dims: [usize; 3]) -> Result<usize> {
    if dims.iter().any(|&d| d == 0 || d > MAX_DIMENSION) {
        return Err(invalid(format!("{what} dims {dims:?}: every axis needs 1 to {MAX_DIMENSION} voxels")));
    }
    Ok(dims.iter().product())
}

/// A finite, affine, non-singular row-major `lps_from_index` as a glam matrix.
fn check_affine(what: &str, m: &[[f64; 4]; 4]) -> Result<DMat4> {
    let lps_from_index = DMat4::from_cols_array_2d(m).transpose();
    if !lps_from_index.is_finite() {
        return Err(invalid(format!("{what} lps_from_index is not finite: {m:?}")));
    }
    #[allow(clippy::float_cmp, reason = "an affine map's last row is exactly (0, 0, 0, 1)")]
    let affine = m[3] == [0.0, 0.0, 0.0, 1.0];
    if !affine {
        return Err(invalid(format!("{what} lps_from_index is not affine (last row {:?})", m[3])));
    }
    let linear = DMat3::from_mat4(lps_from_index);
    let scale = linear.x_axis.length() * linear.y_axis.length() * linear.z_axis.length();
    if scale.is_nan() || scale <= 0.0 || linear.determinant().abs() <= 1e-9 * scale {
        return Err(invalid(format!("{what} lps_from_index is singular: {m:?}")));
    }
    Ok(lps_from_index)
}

/// Entries within 10⁻⁹ (relative) of an integer become that integer (removes the round-off of `inverse · M`).
fn snap(m: DMat4) -> DMat4 {
    let mut cols = m.to_cols_array();
    for x in &mut cols {
        let r = x.round();
        if (*x - r).abs() <= 1e-9 * x.abs().max(1.0) {
            *x = r;
        }
    }
    DMat4::from_cols_array(&cols)
}

fn columns_f32(m: DMat4) -> [[f32; 4]; 4] {
    m.as_mat4().to_cols_array_2d()
}

/// The affine map index ↦ control-texel index (centres at integers) of a control texture over `[min, max]`.
fn ctrl_index_from_ref(dims: [usize; 3], min: DVec3, max: DVec3) -> DMat4 {
    let n = DVec3::new(dims[0] as f64, dims[1] as f64, dims[2] as f64);
    let scale = n / (max - min);
    DMat4::from_cols(
        DVec4::new(scale.x, 0.0, 0.0, 0.0),
        DVec4::new(0.0, scale.y, 0.0, 0.0),
        DVec4::new(0.0, 0.0, scale.z, 0.0),
        (-min * scale - DVec3::splat(0.5)).extend(1.0),
    )
}

impl Plan {
    /// Checks `request` (sizes before anything is allocated) and composes the maps.
    pub fn new(request: &ExportRequest<'_>) -> Result<Self> {
        let source_count = check_dims("source", request.source.dims)?;
        if request.source.samples.len() != source_count {
            return Err(invalid(format!(
                "source dims {:?} need {source_count} samples, got {}",
                request.source.dims,
                request.source.samples.len()
            )));
        }
        let output_len = check_dims("target", request.target.dims)?;
        let output = request.output_type();
        let output_bytes = (output_len as u64).saturating_mul(output.bytes());
        if output_bytes > request.max_output_bytes {
            return Err(invalid(format!(
                "target {:?} of {output:?} is {output_bytes} bytes, above the limit of {} bytes",
                request.target.dims, request.max_output_bytes
            )));
        }
        if output.is_integer() && !request.outside_value.is_finite() {
            return Err(invalid(format!("outside value {} cannot be stored as {output:?}", request.outside_value)));
        }
        if request.slab_slices == Some(0) {
            return Err(invalid("slab_slices must be at least 1".into()));
        }
        let source_lps_from_index = check_affine("source", &request.source.lps_from_index)?;
        let ref_from_target_index = check_affine("target", &request.target.lps_from_index)?;
        let source_index_from_lps = source_lps_from_index.inverse();
        let source_index_from_target_index = snap(source_index_from_lps * ref_from_target_index);
        let mut linear = snap(source_index_from_lps);
        linear.w_axis = DVec4::W;

        let (pullback, pullback_from_target_index) = match request.pullback {
            PullBack::Identity => (PlanPullBack::Identity, DMat4::IDENTITY),
            PullBack::Control(desc) => {
                let prepared = PreparedControl::prepare(&desc, true)?;
                let (min, max) = (prepared.info.box_min_ref, prepared.info.box_max_ref);
                let map = ctrl_index_from_ref(desc.dims, min, max) * ref_from_target_index;
                (PlanPullBack::Control { dims: desc.dims, texels: prepared.texels }, map)
            }
            PullBack::Tps(desc) => {
                desc.validate()?;
                let [nx, ny, nz] = request.target.dims;
                let centre_index = DVec3::new(nx as f64 - 1.0, ny as f64 - 1.0, nz as f64 - 1.0) * 0.5;
                let origin = ref_from_target_index.transform_point3(centre_index);
                let local = desc.local(origin.to_array());
                let finite = local
                    .centres_local
                    .iter()
                    .chain(&local.weights)
                    .chain(&local.linear_minus_identity)
                    .chain([&local.offset_mm])
                    .all(|v| v.iter().all(|x| x.is_finite()));
                if !finite {
                    return Err(invalid("the TPS overflows f32 about the target's centre".into()));
                }
                (PlanPullBack::Tps(local), DMat4::from_translation(-origin) * ref_from_target_index)
            }
        };
        let maps = [source_index_from_target_index, pullback_from_target_index, linear];
        if maps.iter().any(|m| !m.as_mat4().is_finite()) {
            return Err(invalid("the composed index maps overflow f32".into()));
        }
        Ok(Self {
            target_dims: request.target.dims,
            source_dims: request.source.dims,
            source_index_from_target_index: columns_f32(maps[0]),
            pullback_from_target_index: columns_f32(maps[1]),
            source_index_from_lps: columns_f32(maps[2]),
            pullback,
            interpolation: request.interpolation,
            output,
            outside_value: request.outside_value,
            output_len,
            slab_slices: request.slab_slices,
        })
    }
}

/// A value of one of the export's sample types, and how an interpolated value becomes one.
pub(crate) trait Sample: Copy + Default + Send + Sync + 'static {
    /// The accumulator of the interpolation on the CPU: f32, or f64 where f32 is not exact (u32, i32, f64).
    type Acc: Acc;
    fn acc(self) -> Self::Acc;
    /// The f32 the GPU path uploads.
    fn to_f32(self) -> f32;
    /// An interpolated value as this type: rounded half to even and clamped for integers.
    fn from_f64(v: f64) -> Self;
    fn wrap(samples: Vec<Self>) -> ExportedSamples;
}

/// The accumulator arithmetic: f32 or f64.
pub(crate) trait Acc:
    Copy + Send + Sync + std::ops::Add<Output = Self> + std::ops::Sub<Output = Self> + std::ops::Mul<Output = Self>
{
    fn weight(w: f32) -> Self;
    fn to_f64(self) -> f64;
}

impl Acc for f32 {
    #[inline]
    fn weight(w: f32) -> Self {
        w
    }
    #[inline]
    fn to_f64(self) -> f64 {
        f64::from(self)
    }
}

impl Acc for f64 {
    #[inline]
    fn weight(w: f32) -> Self {
        f64::from(w)
    }
    #[inline]
    fn to_f64(self) -> f64 {
        self
    }
}

/// `v.round_ties_even()` without the libm call it becomes on x86-64 without SSE4.1: adding and subtracting 2⁵²
/// rounds to an integer in the default rounding mode (to nearest, ties to even); |v| ≥ 2⁵² is already an integer.
#[inline]
fn round_half_even(v: f64) -> f64 {
    const TWO_52: f64 = 4_503_599_627_370_496.0;
    if v.abs() < TWO_52 {
        let magic = TWO_52.copysign(v);
        (v + magic) - magic
    } else {
        v
    }
}

macro_rules! integer_sample {
    ($t:ty, $acc:ty, $variant:ident) => {
        impl Sample for $t {
            type Acc = $acc;
            #[inline]
            fn acc(self) -> $acc {
                self as $acc
            }
            #[inline]
            fn to_f32(self) -> f32 {
                self as f32
            }
            #[inline]
            fn from_f64(v: f64) -> Self {
                // NaN cannot occur (integer sources, finite outside values); `as` would give 0.
                round_half_even(v).clamp(<$t>::MIN as f64, <$t>::MAX as f64) as $t
            }
            fn wrap(samples: Vec<Self>) -> ExportedSamples {
                ExportedSamples::$variant(samples)
            }
        }
    };
}

integer_sample!(u8, f32, U8);
integer_sample!(i8, f32, I8);
integer_sample!(u16, f32, U16);
integer_sample!(i16, f32, I16);
integer_sample!(u32, f64, U32);
integer_sample!(i32, f64, I32);

impl Sample for f32 {
    type Acc = f32;
    #[inline]
    fn acc(self) -> f32 {
        self
    }
    #[inline]
    fn to_f32(self) -> f32 {
        self
    }
    #[inline]
    fn from_f64(v: f64) -> Self {
        v as f32
    }
    fn wrap(samples: Vec<Self>) -> ExportedSamples {
        ExportedSamples::F32(samples)
    }
}

impl Sample for f64 {
    type Acc = f64;
    #[inline]
    fn acc(self) -> f64 {
        self
    }
    #[inline]
    fn to_f32(self) -> f32 {
        self as f32
    }
    #[inline]
    fn from_f64(v: f64) -> Self {
        v
    }
    fn wrap(samples: Vec<Self>) -> ExportedSamples {
        ExportedSamples::F64(samples)
    }
}

/// `len` default values, or an error instead of an abort when the memory is not there.
pub(crate) fn try_zeroed<T: Sample>(len: usize) -> Result<Vec<T>> {
    let mut v = Vec::new();
    v.try_reserve_exact(len).map_err(|e| {
        invalid(format!("cannot allocate {len} output samples of {} bytes: {e}", std::mem::size_of::<T>()))
    })?;
    v.resize(len, T::default());
    Ok(v)
}

/// Calls `f` with the source samples as a typed slice.
macro_rules! with_samples {
    ($samples:expr, |$s:ident| $body:expr) => {
        match $samples {
            $crate::export::ExportSamples::U8($s) => $body,
            $crate::export::ExportSamples::I8($s) => $body,
            $crate::export::ExportSamples::U16($s) => $body,
            $crate::export::ExportSamples::I16($s) => $body,
            $crate::export::ExportSamples::U32($s) => $body,
            $crate::export::ExportSamples::I32($s) => $body,
            $crate::export::ExportSamples::F32($s) => $body,
            $crate::export::ExportSamples::F64($s) => $body,
        }
    };
}
pub(crate) use with_samples;

/// Reports `done` of `total` slices; `Err(Cancelled)` when the callback says stop.
pub(crate) fn report(progress: &mut dyn FnMut(Progress) -> bool, done: usize, total: usize) -> Result<()> {
    if progress(Progress { slices_done: done, slices_total: total }) {
        Ok(())
    } else {
        Err(GpuError::Cancelled { slices_done: done, slices_total: total })
    }
}

#[cfg(test)]
#[allow(clippy::float_cmp, reason = "rounding and snapping give exact values")]
mod tests {
    use super::*;

    #[test]
    fn rounding_is_half_to_even_and_clamped() {
        assert_eq!(<u8 as Sample>::from_f64(2.5), 2);
        assert_eq!(<u8 as Sample>::from_f64(3.5), 4);
        assert_eq!(<u8 as Sample>::from_f64(-15.9), 0);
        assert_eq!(<u8 as Sample>::from_f64(270.2), 255);
        assert_eq!(<i16 as Sample>::from_f64(-2.5), -2);
        assert_eq!(<i16 as Sample>::from_f64(40_000.0), i16::MAX);
        assert_eq!(<i32 as Sample>::from_f64(-3e10), i32::MIN);
        assert_eq!(<u32 as Sample>::from_f64(4_294_967_294.5), 4_294_967_294);
    }

    #[test]
    fn round_half_even_is_the_std_rule() {
        for v in [0.5, 1.5, 2.5, -0.5, -1.5, -2.5, 0.499_999_999_999_999_94, 1e15 + 0.5, 3e300, -7.25, 1e-300] {
            assert_eq!(round_half_even(v), v.round_ties_even(), "{v}");
        }
        for i in 0..10_000 {
            let v = (f64::from(i) - 5000.0) * 0.173_5;
            assert_eq!(round_half_even(v), v.round_ties_even(), "{v}");
        }
    }

    #[test]
    fn snapping_removes_round_off_only() {
        let m = DMat4::from_cols_array(&[
            1.0 + 1e-13,
            0.0,
            0.0,
            0.0,
            1e-14,
            0.5,
            0.0,
            0.0,
            0.0,
            0.0,
            1.0,
            0.0,
            127.999_999_999_99,
            0.3,
            2.0,
            1.0,
        ]);
        let s = snap(m).to_cols_array();
        assert_eq!(s[0], 1.0);
        assert_eq!(s[4], 0.0);
        assert_eq!(s[5], 0.5);
        assert_eq!(s[12], 128.0);
        assert_eq!(s[13], 0.3);
    }

    #[test]
    fn exactness_in_f32_is_checked_per_value() {
        assert!(ExportSamples::I32(&[-(1 << 24), 1 << 24]).exact_in_f32());
        assert!(!ExportSamples::I32(&[(1 << 24) + 1]).exact_in_f32());
        assert!(!ExportSamples::U32(&[u32::MAX]).exact_in_f32());
        assert!(ExportSamples::F64(&[0.5, f64::NAN, -1024.0]).exact_in_f32());
        assert!(!ExportSamples::F64(&[0.1]).exact_in_f32());
    }
}
