//! [`Volume`]: a voxel grid with its sample type kept, placed in patient space (LPS, mm).

use std::fmt;
use std::path::Path;

use serde::Serialize;

use crate::error::{Error, ErrorKind, Result};
use crate::geometry::{Index, Lps, Point3, Transform, spacing_mm};

/// The stored sample type of a volume.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum SampleType {
    U8,
    I16,
    U16,
    F32,
}

impl SampleType {
    #[must_use]
    pub const fn bytes(self) -> usize {
        match self {
            Self::U8 => 1,
            Self::I16 | Self::U16 => 2,
            Self::F32 => 4,
        }
    }
    #[must_use]
    pub const fn name(self) -> &'static str {
        match self {
            Self::U8 => "u8",
            Self::I16 => "i16",
            Self::U16 => "u16",
            Self::F32 => "f32",
        }
    }
}

/// Voxel samples, x (i) fastest, then y (j), then z (k).
#[derive(Clone, PartialEq)]
pub enum VoxelData {
    U8(Vec<u8>),
    I16(Vec<i16>),
    U16(Vec<u16>),
    F32(Vec<f32>),
}

impl fmt::Debug for VoxelData {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "VoxelData::{}[{}]", self.sample_type().name(), self.len())
    }
}

impl VoxelData {
    #[must_use]
    pub fn sample_type(&self) -> SampleType {
        match self {
            Self::U8(_) => SampleType::U8,
            Self::I16(_) => SampleType::I16,
            Self::U16(_) => SampleType::U16,
            Self::F32(_) => SampleType::F32,
        }
    }
    #[must_use]
    pub fn len(&self) -> usize {
        match self {
            Self::U8(v) => v.len(),
            Self::I16(v) => v.len(),
            Self::U16(v) => v.len(),
            Self::F32(v) => v.len(),
        }
    }
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// One sample as f64.
    #[must_use]
    pub fn get_f64(&self, i: usize) -> f64 {
        match self {
            Self::U8(v) => f64::from(v[i]),
            Self::I16(v) => f64::from(v[i]),
            Self::U16(v) => f64::from(v[i]),
            Self::F32(v) => f64::from(v[i]),
        }
    }
    /// A converted copy as f32 (exact for u8, i16 and u16).
    #[must_use]
    pub fn to_f32(&self) -> Vec<f32> {
        match self {
            Self::U8(v) => v.iter().map(|&x| f32::from(x)).collect(),
            Self::I16(v) => v.iter().map(|&x| f32::from(x)).collect(),
            Self::U16(v) => v.iter().map(|&x| f32::from(x)).collect(),
            Self::F32(v) => v.clone(),
        }
    }
    /// Minimum and maximum of the finite samples, or `None` when there is none.
    #[must_use]
    pub fn finite_range(&self) -> Option<(f64, f64)> {
        fn mm<T: Copy + Into<f64>>(v: &[T]) -> Option<(f64, f64)> {
            v.iter().map(|&x| x.into()).filter(|x: &f64| x.is_finite()).fold(None, |acc, x| match acc {
                None => Some((x, x)),
                Some((lo, hi)) => Some((f64::min(lo, x), f64::max(hi, x))),
            })
        }
        match self {
            Self::U8(v) => mm(v),
            Self::I16(v) => mm(v),
            Self::U16(v) => mm(v),
            Self::F32(v) => mm(v),
        }
    }
    /// Calls `f` with the samples as little-endian bytes, in storage order, a bounded chunk at a time: what
    /// [`Self::to_le_bytes`] returns, without a full-size copy (for checksums of large volumes).
    pub fn for_each_le_chunk(&self, mut f: impl FnMut(&[u8])) {
        let done: std::result::Result<(), std::convert::Infallible> = self.try_for_each_le_chunk(|b| {
            f(b);
            Ok(())
        });
        let Ok(()) = done;
    }

    /// [`Self::for_each_le_chunk`], stopping at the first error `f` returns: how the writers stream the samples.
    pub fn try_for_each_le_chunk<E>(
        &self,
        mut f: impl FnMut(&[u8]) -> std::result::Result<(), E>,
    ) -> std::result::Result<(), E> {
        const CHUNK_SAMPLES: usize = 1 << 16;
        fn each<T: Copy, const N: usize, E>(
            v: &[T],
            le: impl Fn(T) -> [u8; N],
            f: &mut impl FnMut(&[u8]) -> std::result::Result<(), E>,
        ) -> std::result::Result<(), E> {
            let mut buf = Vec::with_capacity(CHUNK_SAMPLES * N);
            for chunk in v.chunks(CHUNK_SAMPLES) {
                buf.clear();
                buf.extend(chunk.iter().flat_map(|&x| le(x)));
                f(&buf)?;
            }
            Ok(())
        }
        match self {
            Self::U8(v) => v.chunks(CHUNK_SAMPLES).try_for_each(f),
            Self::I16(v) => each(v, i16::to_le_bytes, &mut f),
            Self::U16(v) => each(v, u16::to_le_bytes, &mut f),
            Self::F32(v) => each(v, f32::to_le_bytes, &mut f),
        }
    }

    /// The samples as little-endian bytes, in storage order. Used for checksums that
    /// independent readers reproduce (`numpy.asarray(x, '<dtype').tobytes(order='F')`).
    #[must_use]
    pub fn to_le_bytes(&self) -> Vec<u8> {
        match self {
            Self::U8(v) => v.clone(),
            Self::I16(v) => v.iter().flat_map(|x| x.to_le_bytes()).collect(),
            Self::U16(v) => v.iter().flat_map(|x| x.to_le_bytes()).collect(),
            Self::F32(v) => v.iter().flat_map(|x| x.to_le_bytes()).collect(),
        }
    }
}

/// Where `lps_from_index` came from. Readers never return a bare matrix.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum GeometrySource {
    /// NIfTI sform (srow_x/y/z), used because sform_code > 0.
    NiftiSform { code: i32 },
    /// NIfTI qform (quaternion), used because sform_code = 0 and qform_code > 0.
    NiftiQform { code: i32 },
    /// NIfTI pixdim only (both codes 0): axis-aligned, origin 0, as in the NIfTI spec's method 1.
    NiftiPixdim,
    /// DICOM ImagePositionPatient / ImageOrientationPatient / PixelSpacing.
    DicomPatient,
    /// NRRD `space`, `space directions` and `space origin`.
    NrrdSpace,
    /// NRRD without a space: `spacings` only, axis-aligned, origin 0.
    NrrdSpacings,
    /// MetaImage `TransformMatrix`, `ElementSpacing` and `Offset` (ITK's LPS; MetaIO's defaults where missing).
    MetaImage,
    /// FreeSurfer MGH / MGZ: `[Mdc · diag(delta) | c_ras − Mdc · diag(delta) · dims/2]` in RAS, flipped to LPS; when
    /// goodRASflag ≤ 0, FreeSurfer's coronal default (LIA, 1 mm, c_ras 0), with a warning in the metadata.
    Mgh,
    /// MINC: each spatial dimension's `direction_cosines` × `step` as a column, voxel 0 at Σ cosines · `start`, in
    /// RAS, flipped to LPS; MINC's defaults (the axis, 1 mm, 0) where the file leaves them out, with a warning.
    Minc,
    /// OME-Zarr: each space axis's scale, its RFC-4 orientation (or x, y, z as L, P, S) and voxel 0 at the x, y and z
    /// translations, in LPS as ngff-zarr converts an image to ITK's; lengths in mm (`ngff` module docs).
    OmeZarr,
    /// An AFNI dataset's `IJK_TO_DICOM_REAL`, or without it its `ORIENT_SPECIFIC`, `ORIGIN` and `DELTA`, in DICOM's
    /// coordinates, which are LPS ([`crate::afni_dataset`]).
    Afni,
    /// An elastix transform parameter file's fixed grid: `Size`, `Spacing`, `Origin` and `Direction`.
    ElastixParameters,
    /// An ITK transform file's `DisplacementFieldTransform`: its fixed parameters (size, origin, spacing, direction).
    ItkTransformFile,
    /// A Learn2Reg field (`.npz`), which carries no geometry, placed on the grid of the fixed image it was read
    /// against ([`crate::learn2reg::pullback_from_voxels`]).
    Learn2RegFixedImage,
    /// An FSL FNIRT warp (`--fout`, `--cout`), whose FSL coordinates mean nothing without its reference image, placed
    /// on the grid of the fixed image it was read against ([`crate::fnirt::read_pullback`]).
    FnirtReferenceImage,
    /// The file carries no geometry (e.g. a DICOM Secondary Capture without ImagePositionPatient,
    /// ImageOrientationPatient and PixelSpacing): identity directions, unit spacing, origin 0.
    /// Readers add a warning to the metadata when they assume it.
    Assumed,
}

/// Imaging modality, from DICOM (0008,0060) or stated by the caller.
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Modality {
    Ct,
    Mr,
    Other(String),
    Unknown,
}

impl Modality {
    #[must_use]
    pub fn from_dicom(code: &str) -> Self {
        match code.trim() {
            "CT" => Self::Ct,
            "MR" => Self::Mr,
            "" => Self::Unknown,
            other => Self::Other(other.to_string()),
        }
    }
}

/// A linear rescale `value = slope * stored + intercept` and whether it was applied to the samples.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Rescale {
    pub slope: f64,
    pub intercept: f64,
    /// True when the samples in the volume already hold `slope * stored + intercept`.
    pub applied: bool,
}

impl Rescale {
    pub const IDENTITY: Self = Self { slope: 1.0, intercept: 0.0, applied: false };
    #[must_use]
    #[allow(clippy::float_cmp, reason = "identity means exactly slope 1 and intercept 0")]
    pub fn is_identity(&self) -> bool {
        self.slope == 1.0 && self.intercept == 0.0
    }
}

/// Identifying metadata. Every field is optional: not every format carries it.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Metadata {
    pub description: Option<String>,
    pub series_instance_uid: Option<String>,
    pub study_instance_uid: Option<String>,
    pub patient_id: Option<String>,
    pub series_number: Option<i64>,
    /// Physical units of the (rescaled) values, e.g. "HU".
    pub value_units: Option<String>,
    /// Non-fatal problems found while reading (e.g. uneven slice spacing).
    pub warnings: Vec<String>,
}

/// A 3-D voxel grid placed in patient space.
#[derive(Clone, Debug, PartialEq)]
pub struct Volume {
    /// Number of voxels along i, j, k.
    pub dims: [usize; 3],
    /// Samples, i fastest. `data.len() == dims[0] * dims[1] * dims[2]`.
    pub data: VoxelData,
    /// Direction cosines × spacing, plus the LPS position of voxel (0,0,0)'s centre.
    pub lps_from_index: Transform<Lps, Index>,
    pub geometry_source: GeometrySource,
    pub modality: Modality,
    pub rescale: Rescale,
    pub metadata: Metadata,
}

impl Volume {
    /// Builds a volume after checking that `data` has exactly `dims` samples and the geometry is invertible.
    pub fn new(
        path: &Path,
        dims: [usize; 3],
        data: VoxelData,
        lps_from_index: Transform<Lps, Index>,
        geometry_source: GeometrySource,
    ) -> Result<Self> {
        let n = checked_voxel_count(path, dims)?;
        if data.len() != n {
            return Err(Error::invalid(path, format!("{} samples for dims {dims:?} ({n} expected)", data.len())));
        }
        if !lps_from_index.is_valid_affine() {
            return Err(Error::invalid(
                path,
                format!(
                    "the voxel-to-patient matrix is singular or not finite (spacing {:?} mm): {:?}",
                    spacing_mm(&lps_from_index),
                    lps_from_index.rows()
                ),
            ));
        }
        let mut volume = Self {
            dims,
            data,
            lps_from_index,
            geometry_source,
            modality: Modality::Unknown,
            rescale: Rescale::IDENTITY,
            metadata: Metadata::default(),
        };
        volume.note_geometry_warnings();
        Ok(volume)
    }

    /// Warnings about a geometry that is valid but implausible for a medical volume: a spacing outside
    /// [`PLAUSIBLE_SPACING_MM`] (wrong units, a corrupt header).
    #[must_use]
    pub fn geometry_warnings(&self) -> Vec<String> {
        let (lo, hi) = PLAUSIBLE_SPACING_MM;
        let spacing = self.spacing_mm();
        let odd: Vec<String> = ["i", "j", "k"]
            .iter()
            .zip(spacing)
            .filter(|&(_, s)| !(lo..=hi).contains(&s))
            .map(|(axis, s)| format!("{s:e} mm along {axis}"))
            .collect();
        if odd.is_empty() {
            return Vec::new();
        }
        vec![format!(
            "implausible voxel spacing: {} (a medical volume has {lo:e} to {hi:e} mm); check the file's units \
             and geometry",
            odd.join(", ")
        )]
    }

    /// Adds [`Self::geometry_warnings`] to `metadata.warnings`, once (readers that replace the metadata call it
    /// again; it does not repeat a warning).
    pub fn note_geometry_warnings(&mut self) {
        for w in self.geometry_warnings() {
            if !self.metadata.warnings.contains(&w) {
                self.metadata.warnings.push(w);
            }
        }
    }

    #[must_use]
    pub fn spacing_mm(&self) -> [f64; 3] {
        spacing_mm(&self.lps_from_index)
    }

    #[must_use]
    pub fn sample_type(&self) -> SampleType {
        self.data.sample_type()
    }

    /// Linear sample offset of voxel (i, j, k).
    #[must_use]
    pub fn offset(&self, i: usize, j: usize, k: usize) -> usize {
        i + self.dims[0] * (j + self.dims[1] * k)
    }

    /// LPS position of the centre of voxel (i, j, k).
    #[must_use]
    pub fn voxel_lps(&self, i: usize, j: usize, k: usize) -> Point3<Lps> {
        self.lps_from_index.apply_point(Point3::new(i as f64, j as f64, k as f64))
    }
}

/// The voxel spacings (mm) that [`Volume::geometry_warnings`] accepts without a warning: from 0.1 µm
/// (histology, micro-CT) to 1 m. Outside it, the units or the header are almost certainly wrong.
pub const PLAUSIBLE_SPACING_MM: (f64, f64) = (1e-4, 1e3);

/// The index of the centres of the 8 corner voxels of a `dims` grid.
#[must_use]
pub fn corner_indices(dims: [usize; 3]) -> [Point3<Index>; 8] {
    let last = dims.map(|d| d.saturating_sub(1) as f64);
    std::array::from_fn(|c| {
        let pick = |axis: usize| if c & (1 << axis) == 0 { 0.0 } else { last[axis] };
        Point3::new(pick(0), pick(1), pick(2))
    })
}

/// An empty vector with room for `n` samples, allocated fallibly: when the memory cannot be had the
/// error ([`ErrorKind::OutOfMemory`]) names `path` and the size, where `Vec::with_capacity` would abort
/// the process. Every reader allocates its sample buffers through this.
pub fn try_with_capacity<T>(path: &Path, n: usize, what: &str) -> Result<Vec<T>> {
    let mut v = Vec::new();
    v.try_reserve_exact(n).map_err(|_| {
        Error::new(path, ErrorKind::OutOfMemory { what: what.to_string(), bytes: n as u128 * size_of::<T>() as u128 })
    })?;
    Ok(v)
}

/// `n` zeros, allocated fallibly ([`try_with_capacity`]): `vec![0; n]` would abort the process when
/// the memory cannot be had.
pub(crate) fn try_zeros<T: Copy + Default>(path: &Path, n: usize, what: &str) -> Result<Vec<T>> {
    let mut v = try_with_capacity(path, n, what)?;
    v.resize(n, T::default());
    Ok(v)
}

/// Default cap on the bytes of decoded voxel data that a reader allocates (see [`crate::LoadOptions`]).
pub const DEFAULT_MAX_VOXEL_BYTES: u64 = 16 << 30;

/// `dims[0] * dims[1] * dims[2]`, or an error when it overflows or a dimension is 0.
pub fn checked_voxel_count(path: &Path, dims: [usize; 3]) -> Result<usize> {
    if dims.contains(&0) {
        return Err(Error::invalid(path, format!("a dimension is zero: {dims:?}")));
    }
    dims.iter().try_fold(1usize, |acc, &d| acc.checked_mul(d)).ok_or_else(|| {
        Error::new(
            path,
            ErrorKind::TooLarge {
                what: format!("dims {dims:?}"),
                bytes: dims.iter().try_fold(1u128, |a, &d| a.checked_mul(d as u128)).unwrap_or(u128::MAX),
                limit: DEFAULT_MAX_VOXEL_BYTES,
            },
        )
    })
}

/// Checks that `dims` samples of `bytes_per_sample` fit under `limit` bytes; returns the sample count.
/// Call this before allocating anything whose size comes from a file.
pub fn check_allocation(path: &Path, dims: [usize; 3], bytes_per_sample: usize, limit: u64) -> Result<usize> {
    let bytes = dims.iter().try_fold(bytes_per_sample as u128, |a, &d| a.checked_mul(d as u128)).unwrap_or(u128::MAX);
    if bytes > u128::from(limit) {
        return Err(Error::new(path, ErrorKind::TooLarge { what: format!("dims {dims:?}"), bytes, limit }));
    }
    checked_voxel_count(path, dims)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn overflowing_dims_are_rejected_without_allocating() {
        let p = Path::new("x.nii");
        let e = check_allocation(p, [usize::MAX, 2, 2], 2, DEFAULT_MAX_VOXEL_BYTES).expect_err("too large");
        assert!(matches!(e.kind, ErrorKind::TooLarge { .. }), "{e}");
        assert!(e.to_string().starts_with("x.nii: volume too large"), "{e}");
        let e = check_allocation(p, [100_000, 100_000, 100_000], 1, DEFAULT_MAX_VOXEL_BYTES).expect_err("too large");
        assert!(matches!(e.kind, ErrorKind::TooLarge { .. }));
        let e = check_allocation(p, [usize::MAX; 3], 8, DEFAULT_MAX_VOXEL_BYTES).expect_err("overflows u128");
        assert!(matches!(e.kind, ErrorKind::TooLarge { .. }));
        assert!(check_allocation(p, [0, 2, 2], 1, 10).is_err());
        assert_eq!(check_allocation(p, [2, 3, 4], 4, 1000).expect("fits"), 24);
    }

    #[test]
    fn volume_checks_sample_count_and_geometry() {
        let p = Path::new("v");
        let ok =
            Volume::new(p, [2, 2, 1], VoxelData::U8(vec![0; 4]), Transform::identity(), GeometrySource::NiftiPixdim);
        assert!(ok.is_ok());
        let short =
            Volume::new(p, [2, 2, 2], VoxelData::U8(vec![0; 4]), Transform::identity(), GeometrySource::NiftiPixdim);
        assert!(short.is_err());
        let singular = Volume::new(
            p,
            [2, 2, 1],
            VoxelData::U8(vec![0; 4]),
            Transform::from_scale_translation([1.0, 0.0, 1.0], [0.0; 3]),
            GeometrySource::NiftiPixdim,
        );
        assert!(singular.is_err());
    }
}
