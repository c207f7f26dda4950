//! The export's request and result as plain data: what [`crate::export::export_cpu`] and
//! [`crate::export::ExportPass::run`] take and return (the conventions are in the [`crate::export`] docs).

use crate::control::ControlDesc;
use crate::pullback::TpsDesc;

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
    /// Catmull-Rom cubic convolution (interpolating, no prefilter), 64 taps ([`crate::export`] docs).
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

/// Everything an export needs, shared by [`crate::export::export_cpu`] and [`crate::export::ExportPass::run`].
#[derive(Clone, Copy, Debug)]
pub struct ExportRequest<'a> {
    pub source: SourceVolume<'a>,
    pub target: TargetGrid,
    pub pullback: PullBack<'a>,
    pub interpolation: Interpolation,
    pub output: OutputType,
    /// The value of target voxels whose source position is outside the source ([`crate::export`] docs); must be
    /// finite for integer outputs, and is rounded and clamped like the samples.
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exactness_in_f32_is_checked_per_value() {
        assert!(ExportSamples::I32(&[-(1 << 24), 1 << 24]).exact_in_f32());
        assert!(!ExportSamples::I32(&[(1 << 24) + 1]).exact_in_f32());
        assert!(!ExportSamples::U32(&[u32::MAX]).exact_in_f32());
        assert!(ExportSamples::F64(&[0.5, f64::NAN, -1024.0]).exact_in_f32());
        assert!(!ExportSamples::F64(&[0.1]).exact_in_f32());
    }
}
