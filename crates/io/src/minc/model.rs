//! The model MINC 1 and MINC 2 share (module docs of [`super`]): the image's dimensions as a container reader found
//! them ([`Header`]), and from them and the samples the volume ([`volume_of`]): its geometry, the frame chosen and the
//! map from stored samples to real values.

use std::path::Path;

use nalgebra::{Matrix3, Vector3};

use crate::error::{Error, ErrorKind, Result};
use crate::geometry::{Index, Lps, Ras, Transform, lps_from_ras};
use crate::options::LoadOptions;
use crate::sample::{Stored, StoredType, rescaled_type};
use crate::volume::{self, GeometrySource, Rescale, SampleType, Volume, VoxelData};

/// The spatial dimensions' names, x first, and the direction each has by default.
pub(super) const SPATIAL: [(&str, [f64; 3]); 3] =
    [("xspace", [1.0, 0.0, 0.0]), ("yspace", [0.0, 1.0, 0.0]), ("zspace", [0.0, 0.0, 1.0])];

/// The name of the dimension that holds frames.
const TIME: &str = "time";

/// The name of the dimension that holds a vector's components (a displacement grid's x, y and z).
pub(super) const VECTOR: &str = "vector_dimension";

/// One of the image's dimensions, as the file describes it.
#[derive(Clone, Debug, Default)]
pub(super) struct Dimension {
    pub name: String,
    /// Samples along it (the image's shape, which is what counts: a `length` attribute is not read).
    pub len: usize,
    pub start: Option<f64>,
    pub step: Option<f64>,
    pub cosines: Option<Vec<f64>>,
    /// `regular__`, `irregular` or anything a writer put there.
    pub spacing: Option<String>,
}

/// `image-min` and `image-max`: the real range of each slice, over the image's first `dims.len()` dimensions.
#[derive(Clone, Debug)]
pub(super) struct SliceRange {
    /// The dimensions they vary over, by name, slowest first.
    pub dims: Vec<String>,
    pub min: Vec<f64>,
    pub max: Vec<f64>,
}

/// What a container reader found: everything but the samples.
#[derive(Clone, Debug)]
pub(super) struct Header {
    pub dims: Vec<Dimension>,
    pub stored: StoredType,
    /// The image's `valid_range` (or `valid_min` and `valid_max`), when it has one.
    pub valid_range: Option<[f64; 2]>,
    pub range: Option<SliceRange>,
}

impl Header {
    /// The number of samples the image holds (all frames), after checking it against `max_voxel_bytes` and, where the
    /// samples are stored as they are, `file_bytes` (compressed HDF5 chunks pass `None`).
    pub fn checked_len(&self, name: &Path, max_voxel_bytes: u64, file_bytes: Option<u64>) -> Result<usize> {
        let shape: Vec<usize> = self.dims.iter().map(|d| d.len).collect();
        if shape.contains(&0) {
            return Err(Error::invalid(name, format!("the image has a dimension of no samples: {shape:?}")));
        }
        let bytes = shape.iter().try_fold(self.stored.bytes() as u128, |a, &d| a.checked_mul(d as u128));
        let bytes = bytes.unwrap_or(u128::MAX);
        let limit = file_bytes.map_or(max_voxel_bytes, |f| max_voxel_bytes.min(f));
        if bytes > u128::from(limit) {
            let what = format!("the image's {shape:?} samples of {} bytes", self.stored.bytes());
            return Err(match file_bytes {
                Some(f) if bytes > u128::from(f) => Error::truncated(name, format!("{what} do not fit its {f} bytes")),
                _ => Error::new(name, ErrorKind::TooLarge { what, bytes, limit }),
            });
        }
        Ok(usize::try_from(bytes).unwrap_or(usize::MAX) / self.stored.bytes())
    }
}

/// A displacement grid's vectors (LPS mm, i fastest) and grid, from `header` and its samples `raw` in file order: the
/// `vector_dimension`'s three components read as frames are, each mapped to real values.
fn vectors_of<T: Stored>(
    name: &Path,
    header: &Header,
    raw: &[T],
    opts: &LoadOptions,
) -> Result<(VectorGrid, Vec<[f32; 3]>)> {
    let mut layout = Layout::with_frames(name, header, VECTOR, Some(0))?;
    let Some((v, _)) = layout.time.filter(|&(v, _)| header.dims[v].len == 3) else {
        return Err(Error::invalid(name, format!("a displacement grid has a {VECTOR} of 3 components")));
    };
    // A grid must say where it lies; axis-aligned (no direction_cosines, MINC's default) it may be.
    for &a in &layout.spatial {
        let d = &header.dims[a];
        if d.start.is_none() || d.step.is_none() {
            return Err(Error::invalid(
                name,
                format!("a displacement grid must give its place: {} has no start or no step", d.name),
            ));
        }
    }
    let mut warnings = Vec::new();
    let ras_from_index = ras_from_index(name, header, &layout, &mut warnings)?;
    let scale = Scale::of(name, header, T::TYPE)?;
    let dims = layout.spatial.map(|a| header.dims[a].len);
    let mut vectors = volume::try_zeros::<[f32; 3]>(name, dims.iter().product(), "the displacement vectors")?;
    for c in 0..3 {
        layout.time = Some((v, c));
        let (data, _) = samples(name, header, &layout, &scale, raw, dims, opts)?;
        for (n, out) in vectors.iter_mut().enumerate() {
            // RAS to LPS: x and y negated.
            let x = data.get_f64(n) as f32;
            out[c] = if c < 2 { -x } else { x };
        }
    }
    Ok(((dims, lps_from_ras() * ras_from_index), vectors))
}

/// What a reader is asked for: a volume, or a displacement grid's vectors.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Want {
    Volume,
    Vectors,
}

/// What a reader read.
pub(super) enum Decoded {
    Volume(Box<Volume>),
    Vectors(VectorGrid, Vec<[f32; 3]>),
}

/// The volume or the vectors (as `want` says) of `header` and its samples `raw`, all frames, in file order.
pub(super) fn finish<T: Stored>(
    name: &Path,
    header: &Header,
    raw: &[T],
    opts: &LoadOptions,
    want: Want,
) -> Result<Decoded> {
    Ok(match want {
        Want::Volume => Decoded::Volume(Box::new(volume_of(name, header, raw, opts)?)),
        Want::Vectors => {
            let (grid, vectors) = vectors_of(name, header, raw, opts)?;
            Decoded::Vectors(grid, vectors)
        }
    })
}

/// A field's grid: voxels along i, j, k and `lps_from_index`.
pub(super) type VectorGrid = ([usize; 3], Transform<Lps, Index>);

fn volume_of<T: Stored>(name: &Path, header: &Header, raw: &[T], opts: &LoadOptions) -> Result<Volume> {
    let layout = Layout::of(name, header, opts.frame)?;
    let mut warnings = layout.warnings.clone();
    let ras_from_index = ras_from_index(name, header, &layout, &mut warnings)?;
    let scale = Scale::of(name, header, T::TYPE)?;
    let dims = layout.spatial.map(|a| header.dims[a].len);
    let (data, rescale) = samples(name, header, &layout, &scale, raw, dims, opts)?;
    warnings.extend(scale.warning());
    let mut volume = Volume::new(name, dims, data, lps_from_ras() * ras_from_index, GeometrySource::Minc)?;
    volume.rescale = rescale;
    volume.metadata.warnings.extend(warnings);
    Ok(volume)
}

/// Where the image's dimensions are and which frame is read.
#[derive(Clone, Debug)]
struct Layout {
    /// The image dimensions that are i, j and k: the spatial ones, fastest first.
    spatial: [usize; 3],
    /// The image dimension of frames and the frame read, if there is one.
    time: Option<(usize, usize)>,
    warnings: Vec<String>,
}

impl Layout {
    fn of(name: &Path, header: &Header, frame: Option<usize>) -> Result<Self> {
        Self::with_frames(name, header, TIME, frame)
    }

    /// The layout with `frames` (`time`, or `vector_dimension` for a field's components) the dimension whose samples
    /// are chosen one at a time.
    fn with_frames(name: &Path, header: &Header, frames: &str, frame: Option<usize>) -> Result<Self> {
        let names: Vec<&str> = header.dims.iter().map(|d| d.name.as_str()).collect();
        let mut spatial = Vec::new();
        let mut time = None;
        for (a, d) in header.dims.iter().enumerate().rev() {
            if SPATIAL.iter().any(|(s, _)| *s == d.name) {
                if names.iter().filter(|&&n| n == d.name).count() > 1 {
                    return Err(Error::invalid(name, format!("the image names {} twice: {names:?}", d.name)));
                }
                spatial.push(a);
            } else if d.name == frames {
                time = Some(a);
            } else if d.len > 1 {
                let what = if d.name == "vector_dimension" { " (a vector or colour image)" } else { "" };
                return Err(Error::unsupported(
                    name,
                    format!(
                        "the image has a dimension {} of {} samples{what}; warpbench reads one value per voxel, over \
                         xspace, yspace, zspace and perhaps time",
                        d.name, d.len
                    ),
                ));
            }
        }
        let Ok(spatial) = <[usize; 3]>::try_from(spatial) else {
            return Err(Error::unsupported(
                name,
                format!("the image's dimensions are {names:?}; a volume has xspace, yspace and zspace"),
            ));
        };
        let frames = time.map_or(1, |t| header.dims[t].len);
        let chosen = match (frame, frames) {
            (None, 1) => 0,
            (None, frames) => return Err(Error::new(name, ErrorKind::FrameRequired { frames })),
            (Some(t), n) if t >= n => {
                return Err(Error::invalid(name, format!("frame {t} is out of range: the file has {n} frame(s)")));
            }
            (Some(t), _) => t,
        };
        let mut warnings = Vec::new();
        for d in &header.dims {
            match d.spacing.as_deref() {
                Some("irregular") => {
                    return Err(Error::unsupported(
                        name,
                        format!(
                            "{} is irregularly spaced (a position per slice); warpbench reads regular grids",
                            d.name
                        ),
                    ));
                }
                None | Some("regular__" | "regular") => {}
                Some(other) => warnings.push(format!("{}'s spacing says {other:?}; read as regular", d.name)),
            }
        }
        Ok(Self { spatial, time: time.map(|t| (t, chosen)), warnings })
    }
}

/// The RAS geometry of the spatial dimensions (module docs), with a warning naming the defaults assumed.
fn ras_from_index(
    name: &Path,
    header: &Header,
    layout: &Layout,
    warnings: &mut Vec<String>,
) -> Result<Transform<Ras, Index>> {
    let mut linear = Matrix3::zeros();
    let mut origin = Vector3::zeros();
    let mut assumed = Vec::new();
    for (axis, &a) in layout.spatial.iter().enumerate() {
        let d = &header.dims[a];
        let mut missing = Vec::new();
        let default = SPATIAL.iter().find(|(s, _)| *s == d.name).map_or([0.0; 3], |(_, c)| *c);
        let cosines = match &d.cosines {
            Some(c) if c.len() == 3 && c.iter().all(|x| x.is_finite()) && c.iter().any(|&x| x != 0.0) => {
                Vector3::new(c[0], c[1], c[2])
            }
            Some(c) => {
                return Err(Error::invalid(name, format!("{}'s direction_cosines are {c:?}, not a direction", d.name)));
            }
            None => {
                missing.push("direction_cosines");
                Vector3::from(default)
            }
        };
        let step = match d.step {
            Some(s) if s.is_finite() && s != 0.0 => s,
            Some(s) => return Err(Error::invalid(name, format!("{}'s step is {s}", d.name))),
            None => {
                missing.push("step");
                1.0
            }
        };
        let start = match d.start {
            Some(s) if s.is_finite() => s,
            Some(s) => return Err(Error::invalid(name, format!("{}'s start is {s}", d.name))),
            None => {
                missing.push("start");
                0.0
            }
        };
        if !missing.is_empty() {
            assumed.push(format!("{} ({})", d.name, missing.join(", ")));
        }
        linear.set_column(axis, &(cosines * step));
        origin += cosines * start;
    }
    if !assumed.is_empty() {
        warnings.push(format!(
            "the file leaves out {}; MINC's defaults (start 0, step 1 mm, the axis's own direction) were used, so \
             the volume is not placed where it was scanned",
            assumed.join(", ")
        ));
    }
    Ok(Transform::from_linear_translation(linear, [origin.x, origin.y, origin.z]))
}

/// The map from stored samples to real values (module docs): per block of `block` samples in file order.
#[derive(Clone, Debug)]
enum Scale {
    /// Float samples, or integers whose every slice maps to itself: the values as stored (after the clip).
    Identity { valid: [f64; 2] },
    /// `clip(v) · slope[b] + inter[b]` for the samples of block b.
    Slices { valid: [f64; 2], slope: Vec<f64>, inter: Vec<f64>, block: usize },
    /// Float samples: no clip, no map.
    Float,
}

impl Scale {
    fn of(name: &Path, header: &Header, stored: StoredType) -> Result<Self> {
        if matches!(stored, StoredType::F32 | StoredType::F64) {
            return Ok(Self::Float);
        }
        let (lo, hi) = type_range(stored);
        let valid = match header.valid_range {
            Some([a, b]) => {
                if !(a.is_finite() && b.is_finite() && a >= lo && b <= hi && a < b) {
                    return Err(Error::invalid(
                        name,
                        format!(
                            "the image's valid_range [{a}, {b}] is not an increasing range inside its type's [{lo}, {hi}]"
                        ),
                    ));
                }
                [a, b]
            }
            None => [lo, hi],
        };
        let Some(range) = &header.range else {
            return Err(Error::unsupported(
                name,
                "the image stores integers but has no image-min and image-max, which give the real values they stand \
                 for",
            ));
        };
        let k = range.dims.len();
        let names: Vec<&str> = header.dims.iter().map(|d| d.name.as_str()).collect();
        if k >= names.len() || range.dims.iter().zip(&names).any(|(a, b)| a != b) {
            return Err(Error::invalid(
                name,
                format!(
                    "image-min and image-max vary over {:?}, which is not a leading part of the image's dimensions \
                     {names:?}",
                    range.dims
                ),
            ));
        }
        let slices: usize = header.dims[..k].iter().map(|d| d.len).product();
        if range.min.len() != slices || range.max.len() != slices {
            return Err(Error::invalid(
                name,
                format!(
                    "image-min has {} and image-max {} values where {:?} have {slices} slices",
                    range.min.len(),
                    range.max.len(),
                    range.dims
                ),
            ));
        }
        let block: usize = header.dims[k..].iter().map(|d| d.len).product();
        let span = valid[1] - valid[0];
        let mut slope = Vec::with_capacity(slices);
        let mut inter = Vec::with_capacity(slices);
        for (s, (&mn, &mx)) in range.min.iter().zip(&range.max).enumerate() {
            if !(mn.is_finite() && mx.is_finite()) {
                return Err(Error::invalid(name, format!("slice {} has image-min {mn} and image-max {mx}", s + 1)));
            }
            let m = (mx - mn) / span;
            slope.push(m);
            inter.push(mn - valid[0] * m);
        }
        #[allow(clippy::float_cmp, reason = "identity means exactly slope 1 and intercept 0")]
        if slope.iter().all(|&m| m == 1.0) && inter.iter().all(|&b| b == 0.0) {
            return Ok(Self::Identity { valid });
        }
        Ok(Self::Slices { valid, slope, inter, block })
    }

    /// The warning of slices mapped differently.
    fn warning(&self) -> Option<String> {
        match self {
            Self::Slices { slope, inter, .. }
                if slope.iter().zip(inter).any(|(m, b)| (m, b) != (&slope[0], &inter[0])) =>
            {
                Some(format!(
                    "image-min and image-max differ between slices; each slice was mapped with its own (the first: \
                     slope {}, intercept {})",
                    slope[0], inter[0]
                ))
            }
            _ => None,
        }
    }
}

/// The range of an integer type, as f64.
fn type_range(t: StoredType) -> (f64, f64) {
    match t {
        StoredType::U8 => (0.0, f64::from(u8::MAX)),
        StoredType::I8 => (f64::from(i8::MIN), f64::from(i8::MAX)),
        StoredType::U16 => (0.0, f64::from(u16::MAX)),
        StoredType::I16 => (f64::from(i16::MIN), f64::from(i16::MAX)),
        StoredType::U32 => (0.0, f64::from(u32::MAX)),
        StoredType::I32 => (f64::from(i32::MIN), f64::from(i32::MAX)),
        StoredType::U64 => (0.0, u64::MAX as f64),
        StoredType::I64 => (i64::MIN as f64, i64::MAX as f64),
        StoredType::F32 | StoredType::F64 => (f64::NEG_INFINITY, f64::INFINITY),
    }
}

/// The chosen frame's samples, i fastest, as real values in the volume's sample type, and the rescale recorded.
fn samples<T: Stored>(
    name: &Path,
    header: &Header,
    layout: &Layout,
    scale: &Scale,
    raw: &[T],
    dims: [usize; 3],
    opts: &LoadOptions,
) -> Result<(VoxelData, Rescale)> {
    let shape: Vec<usize> = header.dims.iter().map(|d| d.len).collect();
    if raw.len() != shape.iter().product::<usize>() {
        return Err(Error::invalid(name, format!("the image holds {} samples for its shape {shape:?}", raw.len())));
    }
    let mut strides = vec![1usize; shape.len()];
    for a in (0..shape.len().saturating_sub(1)).rev() {
        strides[a] = strides[a + 1] * shape[a + 1];
    }
    let base = layout.time.map_or(0, |(t, f)| f * strides[t]);
    let [si, sj, sk] = layout.spatial.map(|a| strides[a]);
    // The file-order index of each voxel, i fastest.
    let index = move |n: usize| {
        let (i, rest) = (n % dims[0], n / dims[0]);
        base + i * si + (rest % dims[1]) * sj + (rest / dims[1]) * sk
    };
    let n = volume::check_allocation(name, dims, 4, opts.max_voxel_bytes)?;
    let (target, rescale, value): (SampleType, Rescale, Box<dyn Fn(usize) -> f64 + '_>) = match scale {
        Scale::Float => (T::TYPE.unscaled(), Rescale::IDENTITY, Box::new(|n| raw[index(n)].to_f64())),
        Scale::Identity { valid: [a, b] } => {
            // The clip keeps every value inside the stored type, so its unscaled type holds it.
            (T::TYPE.unscaled(), Rescale::IDENTITY, Box::new(move |n| raw[index(n)].to_f64().clamp(*a, *b)))
        }
        Scale::Slices { valid: [a, b], slope, inter, block } => {
            let integral = slope.iter().chain(inter).all(|x| x.fract() == 0.0 && x.abs() < 1e12);
            let (lo, hi) = slope.iter().zip(inter).fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), (m, c)| {
                let (p, q) = (a * m + c, b * m + c);
                (lo.min(p).min(q), hi.max(p).max(q))
            });
            let rescale = Rescale { slope: slope[0], intercept: inter[0], applied: true };
            let value = move |n: usize| {
                let at = index(n);
                let s = at / block;
                raw[at].to_f64().clamp(*a, *b) * slope[s] + inter[s]
            };
            (rescaled_type(integral, lo, hi), rescale, Box::new(value))
        }
    };
    let mut data = VoxelData::try_empty(name, target, n, "the voxel samples")?;
    data.extend_from((0..n).map(value));
    Ok((data, rescale))
}
