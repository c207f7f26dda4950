//! The export's sample types as Rust types ([`Sample`]), the accumulator arithmetic ([`Acc`]) and the dispatch from
//! [`ExportSamples`] to a typed slice (`with_samples!`).

use super::request::ExportedSamples;
use crate::error::{GpuError, Result};

/// A value of one of the export's sample types, and how an interpolated value becomes one.
pub(crate) trait Sample: bytemuck::Pod + Default + Send + Sync + 'static {
    /// The accumulator of the interpolation on the CPU: f32, or f64 where f32 is not exact (u32, i32, f64).
    type Acc: Acc;
    fn acc(self) -> Self::Acc;
    /// Writes `src` as the texels the GPU path uploads (little-endian, as GPU buffers are): the samples' own bytes,
    /// except f64, which the GPU reads as f32 (the GPU path takes f64 samples only when every one is exact in f32).
    fn write_texels(mut dst: wgpu::WriteOnly<'_, [u8]>, src: &[Self]) {
        dst.copy_from_slice(bytemuck::cast_slice(src));
    }
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
    fn write_texels(dst: wgpu::WriteOnly<'_, [u8]>, src: &[Self]) {
        dst.write_iter(src.iter().flat_map(|&v| (v as f32).to_le_bytes()));
    }
    #[inline]
    fn from_f64(v: f64) -> Self {
        v
    }
    fn wrap(samples: Vec<Self>) -> ExportedSamples {
        ExportedSamples::F64(samples)
    }
}

/// An empty `Vec` with room for `len` output samples, or [`GpuError::InvalidInput`] when the system refuses it.
pub(crate) fn try_reserved<T: Sample>(len: usize) -> Result<Vec<T>> {
    let mut v = Vec::new();
    v.try_reserve_exact(len).map_err(|e| {
        GpuError::InvalidInput(format!(
            "cannot allocate {len} output samples of {} bytes: {e}",
            std::mem::size_of::<T>()
        ))
    })?;
    Ok(v)
}

/// Calls `f` with the source samples as a typed slice.
macro_rules! with_samples {
    ($samples:expr, |$s:ident| $body:expr) => {
        match $samples {
            $crate::export::request::ExportSamples::U8($s) => $body,
            $crate::export::request::ExportSamples::I8($s) => $body,
            $crate::export::request::ExportSamples::U16($s) => $body,
            $crate::export::request::ExportSamples::I16($s) => $body,
            $crate::export::request::ExportSamples::U32($s) => $body,
            $crate::export::request::ExportSamples::I32($s) => $body,
            $crate::export::request::ExportSamples::F32($s) => $body,
            $crate::export::request::ExportSamples::F64($s) => $body,
        }
    };
}
pub(crate) use with_samples;

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
}
