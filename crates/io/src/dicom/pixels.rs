//! Pixels (steps 4 and 5 of [`super`]): each file's frames decoded into one buffer of the stored type, the stored
//! bits masked and sign-extended, then the rescale and the output sample type.

use std::borrow::Cow;
use std::path::Path;

use dicom_core::PrimitiveValue;
use dicom_core::value::Value;
use dicom_dictionary_std::tags;
use dicom_pixeldata::PixelDecoder;

use super::codecs::{check_j2k, check_jpeg, decode_jpeg_ls, decode_rle};
use super::geometry::Plan;
use super::header::{Header, PixelFormat, parse_pixel_format};
use super::input::{Source, error_chain};
use super::transfer_syntax::{Codec, TransferSyntax};
use crate::error::{Error, ErrorKind, Result};
use crate::options::LoadOptions;
use crate::sample::{Stored, StoredType, rescaled_type};
use crate::volume::{self, Rescale, SampleType, VoxelData, try_zeros};

/// The stored type of `fmt`'s samples: BitsAllocated 8, 16 or 32, signed when PixelRepresentation is 1.
pub(super) fn stored_type(path: &Path, fmt: &PixelFormat) -> Result<StoredType> {
    Ok(match (fmt.bits_allocated, fmt.signed) {
        (8, false) => StoredType::U8,
        (8, true) => StoredType::I8,
        (16, false) => StoredType::U16,
        (16, true) => StoredType::I16,
        (32, false) => StoredType::U32,
        (32, true) => StoredType::I32,
        (b, _) => {
            return Err(Error::unsupported(path, format!("BitsAllocated (0028,0100) {b} (only 8, 16 and 32)")));
        }
    })
}

/// `f(i, v[i])` for every sample, into a buffer allocated fallibly. When `S` and `T` have the same layout, std
/// collects a vector's own `into_iter` in place (no second buffer, nothing to allocate); otherwise the output is
/// allocated with [`volume::try_with_capacity`].
fn try_convert<S, T>(path: &Path, v: Vec<S>, f: impl FnMut((usize, S)) -> T) -> Result<Vec<T>> {
    if size_of::<S>() == size_of::<T>() && align_of::<S>() == align_of::<T>() {
        return Ok(v.into_iter().enumerate().map(f).collect());
    }
    let mut out = volume::try_with_capacity(path, v.len(), "the converted samples")?;
    out.extend(v.into_iter().enumerate().map(f));
    Ok(out)
}

/// How to turn the raw bits of one sample into its value.
#[derive(Clone, Copy, Debug)]
struct BitLayout {
    shift: u32,
    bits: u32,
    signed: bool,
}

impl BitLayout {
    fn new(path: &Path, fmt: &PixelFormat, native: bool) -> Result<Self> {
        let (alloc, stored, high) =
            (u32::from(fmt.bits_allocated), u32::from(fmt.bits_stored), u32::from(fmt.high_bit));
        if stored == 0 || stored > alloc {
            return Err(Error::invalid(path, format!("BitsStored (0028,0101) {stored} with BitsAllocated {alloc}")));
        }
        // Codecs return values in the low bits; native data may place them at HighBit.
        let shift = if native && high < alloc && high + 1 >= stored { high + 1 - stored } else { 0 };
        Ok(Self { shift, bits: stored, signed: fmt.signed })
    }

    #[inline]
    fn value(self, raw: u32) -> i64 {
        let v = (raw >> self.shift) & (u32::MAX >> (32 - self.bits));
        if self.signed && self.bits > 0 && (v >> (self.bits - 1)) & 1 == 1 {
            i64::from(v) - (1i64 << self.bits)
        } else {
            i64::from(v)
        }
    }
}

/// The samples of one frame, as found: bytes (little-endian) or 16-bit words.
#[derive(Clone, Copy)]
enum FrameSamples<'a> {
    Bytes(&'a [u8]),
    Words(&'a [u16]),
}

/// Decodes the files of `series` into one buffer of `T` (sized `total`, checked by the caller) and applies the
/// rescale. Files are decoded one at a time in the order of their first slice, each dropped before the next.
pub(super) fn decode_series<T: Stored + Default>(
    label: &Path,
    sources: &[Source],
    series: &[Header],
    syntaxes: &[TransferSyntax],
    plan: &Plan,
    total: usize,
    opts: &mut LoadOptions,
) -> Result<(VoxelData, Rescale, Vec<String>)> {
    let dims = plan.dims;
    let slice_len = dims[0] * dims[1];
    let mut stored = try_zeros::<T>(label, total, "the stored pixels")?;
    let mut ranges = vec![(0i64, 0i64); dims[2]];
    let mut slots_of: Vec<Vec<(usize, usize)>> = vec![Vec::new(); series.len()];
    for (k, s) in plan.slots.iter().enumerate() {
        slots_of[s.header].push((s.frame, k));
    }
    let mut order: Vec<usize> = (0..series.len()).collect();
    order.sort_by_key(|&h| slots_of[h].iter().map(|&(_, k)| k).min().unwrap_or(usize::MAX));
    let n_files = order.len() as u64;
    for (done, &hi) in order.iter().enumerate() {
        opts.report(label, "decoding slices", done as u64, n_files)?;
        let h = &series[hi];
        let src = &sources[h.source];
        let Ok((hfmt, _)) = &h.image else { continue };
        decode_file(src, syntaxes[hi], hfmt, &slots_of[hi], slice_len, &mut stored, &mut ranges)?;
    }
    opts.report(label, "decoding slices", n_files, n_files)?;

    let rescales: Vec<(f64, f64)> = plan.slots.iter().map(|s| (s.geom.slope, s.geom.intercept)).collect();
    finalize(label, stored, slice_len, &rescales, &ranges, dims, opts)
}

/// Writes one frame into slice `k` of `dst`; returns the (min, max) of the stored values.
fn store_frame<T: Stored>(
    dst: &mut [T],
    k: usize,
    n: usize,
    src: FrameSamples,
    bytes: usize,
    layout: BitLayout,
) -> (i64, i64) {
    fn fill<T: Stored>(dst: &mut [T], raws: impl Iterator<Item = u32>, layout: BitLayout) -> (i64, i64) {
        let mut lo = i64::MAX;
        let mut hi = i64::MIN;
        for (d, raw) in dst.iter_mut().zip(raws) {
            let v = layout.value(raw);
            lo = lo.min(v);
            hi = hi.max(v);
            *d = T::from_i64(v);
        }
        (lo, hi)
    }
    let dst = &mut dst[k * n..(k + 1) * n];
    match (src, bytes) {
        (FrameSamples::Bytes(b), 1) => fill(dst, b.iter().map(|&x| u32::from(x)), layout),
        (FrameSamples::Bytes(b), 2) => {
            fill(dst, b.chunks_exact(2).map(|c| u32::from(u16::from_le_bytes([c[0], c[1]]))), layout)
        }
        (FrameSamples::Bytes(b), _) => {
            fill(dst, b.chunks_exact(4).map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]])), layout)
        }
        (FrameSamples::Words(w), 2) => fill(dst, w.iter().map(|&x| u32::from(x)), layout),
        (FrameSamples::Words(w), _) => {
            fill(dst, w.chunks_exact(2).map(|c| u32::from(c[0]) | (u32::from(c[1]) << 16)), layout)
        }
    }
}

/// Opens one file fully, decodes its frames and stores them at their slots.
fn decode_file<T: Stored>(
    src: &Source,
    ts: TransferSyntax,
    fmt: &PixelFormat,
    slots: &[(usize, usize)],
    slice_len: usize,
    dst: &mut [T],
    ranges: &mut [(i64, i64)],
) -> Result<()> {
    let path = src.path();
    let native = ts.codec() == Codec::Native;
    // Little-endian native pixels are copied straight from the file's bytes (peak: file + volume);
    // big-endian ones go through dicom-rs, which swaps the words, and deflated data sets through
    // dicom-rs, which inflates them.
    let (mut obj, raw) = if ts.pixels_are_file_bytes() {
        let (obj, bytes, range) = src.open_native_pixels()?;
        (obj, Some((bytes, range)))
    } else {
        (src.open(false)?, None)
    };
    // The file is read again: check that it still matches its header.
    let now = parse_pixel_format(&obj).map_err(|e| Error::invalid(path, e))?;
    if now != *fmt {
        return Err(Error::invalid(path, "the file changed while it was being read"));
    }
    let layout = BitLayout::new(path, fmt, native)?;
    let bytes = usize::from(fmt.bits_allocated / 8);
    let frame_bytes = slice_len * bytes;
    let needed = frame_bytes.checked_mul(fmt.frames).ok_or_else(|| Error::invalid(path, "frame size overflows"))?;
    let truncated = |have: usize| {
        Error::truncated(
            path,
            format!(
                "PixelData (7FE0,0010) has {have} bytes, {needed} needed for {} frame(s) of {}x{}x{} bits",
                fmt.frames, fmt.cols, fmt.rows, fmt.bits_allocated
            ),
        )
    };
    let decoded: Vec<u8>;
    let samples: FrameData = if let Some((bytes, range)) = &raw {
        FrameData::Bytes(Cow::Borrowed(&bytes[range.clone()]))
    } else {
        let pixel =
            obj.get(tags::PIXEL_DATA).ok_or_else(|| Error::invalid(path, "PixelData (7FE0,0010) is missing"))?;
        match pixel.value() {
            Value::Primitive(p) if native => match p {
                PrimitiveValue::U16(w) if bytes >= 2 => FrameData::Words(w),
                PrimitiveValue::U8(b) => FrameData::Bytes(Cow::Borrowed(b)),
                other => FrameData::Bytes(other.to_bytes()),
            },
            Value::PixelSequence(seq) if ts.codec() == Codec::Rle => {
                decoded = decode_rle(path, seq.fragments(), fmt, bytes)?;
                FrameData::Bytes(Cow::Borrowed(&decoded))
            }
            Value::PixelSequence(seq) if ts.codec() == Codec::JpegLs => {
                decoded = decode_jpeg_ls(path, seq.fragments(), fmt, bytes)?;
                FrameData::Bytes(Cow::Borrowed(&decoded))
            }
            Value::PixelSequence(seq) if !native => {
                match ts.codec() {
                    Codec::Jpeg => check_jpeg(path, seq.fragments(), fmt)?,
                    Codec::Jpeg2000 => check_j2k(path, seq.fragments(), fmt)?,
                    Codec::Native | Codec::Rle | Codec::JpegLs | Codec::Pixeldata => {}
                }
                // dicom-pixeldata also parses windows, LUTs and rescale (and fails on odd ones): we read
                // those ourselves, so remove them before decoding.
                for tag in [
                    tags::WINDOW_CENTER,
                    tags::WINDOW_WIDTH,
                    tags::VOILUT_FUNCTION,
                    tags::VOILUT_SEQUENCE,
                    tags::RESCALE_INTERCEPT,
                    tags::RESCALE_SLOPE,
                    tags::SHARED_FUNCTIONAL_GROUPS_SEQUENCE,
                    tags::PER_FRAME_FUNCTIONAL_GROUPS_SEQUENCE,
                ] {
                    obj.remove_element(tag);
                }
                let name = ts.name();
                let pd = obj.decode_pixel_data().map_err(|e| {
                    Error::new(path, ErrorKind::Dicom(format!("cannot decode {name} pixel data: {}", error_chain(&e))))
                })?;
                decoded = pd.into_data();
                FrameData::Bytes(Cow::Borrowed(&decoded))
            }
            _ => {
                return Err(Error::invalid(
                    path,
                    format!(
                        "PixelData (7FE0,0010) is {} for transfer syntax {}",
                        if native { "encapsulated" } else { "not encapsulated" },
                        ts.uid()
                    ),
                ));
            }
        }
    };
    let have = samples.len_bytes();
    if have < needed {
        return Err(truncated(have));
    }
    for &(frame, k) in slots {
        let frame_src = samples.frame(frame, frame_bytes, bytes);
        ranges[k] = store_frame(dst, k, slice_len, frame_src, bytes, layout);
    }
    Ok(())
}

/// All frames of one object.
enum FrameData<'a> {
    Bytes(Cow<'a, [u8]>),
    Words(&'a [u16]),
}

impl FrameData<'_> {
    fn len_bytes(&self) -> usize {
        match self {
            Self::Bytes(b) => b.len(),
            Self::Words(w) => w.len() * 2,
        }
    }
    /// Frame `f`; the caller has checked the length.
    fn frame(&self, f: usize, frame_bytes: usize, bytes: usize) -> FrameSamples<'_> {
        match self {
            Self::Bytes(b) => FrameSamples::Bytes(&b[f * frame_bytes..(f + 1) * frame_bytes]),
            Self::Words(w) => {
                let _ = bytes; // words only hold 16- and 32-bit samples (bytes >= 2)
                let words = frame_bytes / 2;
                FrameSamples::Words(&w[f * words..(f + 1) * words])
            }
        }
    }
}

/// Applies the rescale and picks the output sample type (docs/fixture-manifest.md).
fn finalize<T: Stored>(
    label: &Path,
    stored: Vec<T>,
    slice_len: usize,
    rescales: &[(f64, f64)],
    ranges: &[(i64, i64)],
    dims: [usize; 3],
    opts: &LoadOptions,
) -> Result<(VoxelData, Rescale, Vec<String>)> {
    let mut warnings = Vec::new();
    let identity = rescales.iter().all(|&(s, b)| is_identity(s, b));
    let (slope0, intercept0) = rescales.first().copied().unwrap_or((1.0, 0.0));
    if rescales.iter().any(|&r| r != (slope0, intercept0)) {
        warnings.push(format!(
            "RescaleSlope/RescaleIntercept differ between slices; each slice was rescaled with its own \
             (the first is slope {slope0}, intercept {intercept0})"
        ));
    }
    if identity {
        let output = T::TYPE.unscaled();
        let data = match T::into_voxels(stored) {
            Ok(data) => data,
            Err(stored) => {
                // A widening (i8 to i16) needs more than the stored bytes checked so far.
                volume::check_allocation(label, dims, output.bytes(), opts.max_voxel_bytes)?;
                convert(label, output, stored, |(_, x)| x)?
            }
        };
        return Ok((data, Rescale::IDENTITY, warnings));
    }
    let integer =
        rescales.iter().all(|&(s, b)| s.fract() == 0.0 && b.fract() == 0.0 && s.abs() < 1e9 && b.abs() < 1e12);
    let (lo, hi) =
        rescales.iter().zip(ranges).fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), (&(s, b), &(a, z))| {
            let (p, q) = (s * a as f64 + b, s * z as f64 + b);
            (lo.min(p).min(q), hi.max(p).max(q))
        });
    let rescale = Rescale { slope: slope0, intercept: intercept0, applied: true };
    let target = rescaled_type(integer, lo, hi);
    volume::check_allocation(label, dims, target.bytes(), opts.max_voxel_bytes)?;
    let data = convert(label, target, stored, |(i, x)| {
        let (s, b) = rescales[i / slice_len];
        s * x.to_i64() as f64 + b
    })?;
    Ok((data, rescale, warnings))
}

/// `f(i, v[i])` for every sample, cast to `output`, converted in place where the layouts match
/// ([`try_convert`]).
fn convert<S: Stored, V: Stored>(
    label: &Path,
    output: SampleType,
    v: Vec<S>,
    mut f: impl FnMut((usize, S)) -> V,
) -> Result<VoxelData> {
    Ok(match output {
        SampleType::U8 => VoxelData::U8(try_convert(label, v, |x| f(x).as_u8())?),
        SampleType::I16 => VoxelData::I16(try_convert(label, v, |x| f(x).as_i16())?),
        SampleType::U16 => VoxelData::U16(try_convert(label, v, |x| f(x).as_u16())?),
        SampleType::F32 => VoxelData::F32(try_convert(label, v, |x| f(x).as_f32())?),
    })
}

/// True when any slice has a non-identity rescale (CT values are then HU).
pub(super) fn has_rescale(plan: &Plan) -> bool {
    plan.slots.iter().any(|s| !is_identity(s.geom.slope, s.geom.intercept))
}

/// Exactly slope 1 and intercept 0 (the manifest rule compares exactly).
#[allow(clippy::float_cmp)]
fn is_identity(slope: f64, intercept: f64) -> bool {
    slope == 1.0 && intercept == 0.0
}
