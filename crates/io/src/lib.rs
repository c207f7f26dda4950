//! # warpbench-io
//!
//! Readers and writers for the volumes and landmarks that warpbench registers, all placed in one
//! patient space: **LPS, in mm** (see `docs/spaces.md`).
//!
//! - [`open`] / [`LoadOptions::open`]: read a NIfTI-1/2 (`.nii`, `.nii.gz`, or a `.hdr`/`.img` pair), NRRD (`.nrrd`, `.nhdr`),
//!   MetaImage (`.mha`, `.mhd`), FreeSurfer MGH (`.mgh`, `.mgz`), MINC (`.mnc`) or AFNI (`.HEAD`/`.BRIK`) file, an OME-Zarr folder
//!   ([`ngff`]), a DICOM series folder or a single DICOM file into a [`Volume`]; [`write_volume`] writes one in the
//!   format its name says.
//! - [`nifti`], [`nrrd`], [`metaimage`], [`mgh`], [`dicom`]: the format modules, with their writers.
//! - [`landmarks`]: landmark pairs and point lists: BigWarp CSV and JSON, Slicer `.mrk.json` / `.fcsv`, elastix
//!   point files.
//! - [`geometry`]: points, vectors and transforms that carry their space in the type.
//! - [`itk_tfm`]: ITK transform files (`.tfm`) holding one transform: affine, thin-plate spline or cubic B-spline;
//!   and the ANTs / ITK MATLAB affine (`.mat`).
//! - [`dicom_reg`]: a linear registration between two DICOM series as a DICOM Spatial Registration object.
//! - [`itk_h5`]: ITK's HDF5 transform files (`.h5`: ANTs' `Composite.h5`, 3D Slicer's transforms), read as a chain
//!   of affines, B-splines and displacement fields.
//!
//! Every error names the file and the problem ([`Error`]); bad input never panics, sizes are
//! checked before allocating, and writers replace their output atomically ([`write_atomic`]).

pub mod afni;
pub mod afni_dataset;
pub mod atomic;
pub mod dicom;
pub mod dicom_reg;
pub mod dicom_source;
pub mod dicom_write;
pub mod displacement;
pub mod elastix;
pub mod error;
mod files;
pub mod fnirt;
pub mod fsl;
pub mod geometry;
mod hdf5_guard;
pub mod itk_chain;
pub mod itk_h5;
pub mod itk_tfm;
pub mod landmarks;
pub mod learn2reg;
pub mod lta;
pub mod metaimage;
pub mod mgh;
pub mod minc;
pub mod mni_xfm;
pub mod ngff;
pub mod nifti;
pub mod nrrd;
pub mod options;
mod pargz;
pub mod sample;
pub mod series;
mod stream;
pub mod transform_file;
pub mod volume;

use std::path::Path;

pub use atomic::write_atomic;
/// The DICOM reader's JPEG-LS decoder, which benches and tests also call on its own.
pub use dicom::jpegls;
pub use error::{Error, ErrorKind, Result};
pub use options::{LoadOptions, Part, Progress};
pub use series::SeriesSummary;
pub use volume::{GeometrySource, Metadata, Modality, Rescale, SampleType, Volume, VoxelData};

use files::{check_file_or_folder, read_up_to};

/// A volume file format.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    Nifti,
    Nrrd,
    /// A DICOM series folder, or one DICOM file (possibly enhanced multi-frame).
    Dicom,
    /// MetaImage: `.mha`, or a `.mhd` header with its data file.
    MetaImage,
    /// FreeSurfer MGH: `.mgh`, or gzip-compressed `.mgz` (`.mgh.gz`). Known by its name only: it has no magic bytes.
    Mgh,
    /// MINC: `.mnc` (or `.mnc.gz`), MINC 1 (netCDF) or MINC 2 (HDF5).
    Minc,
    /// OME-Zarr (NGFF) 0.4 to 0.6: a folder holding a Zarr store.
    OmeZarr,
    /// An AFNI dataset: a `.HEAD` beside a `.BRIK` (or `.BRIK.gz`), named by either. Known by its name only.
    Afni,
}

impl Format {
    /// Detects the format of `path`: folders are OME-Zarr images when they hold a Zarr store, else DICOM series; files by extension (the only way for MGH), then by
    /// magic bytes (`NRRD`, `DICM` at 128, gzip or a NIfTI header, `ObjectType =` for MetaImage, `CDF` for MINC 1).
    #[allow(clippy::case_sensitive_file_extension_comparisons, reason = "the name is lowercased first")]
    pub fn detect(path: &Path) -> Result<Self> {
        // AFNI's bare dataset names (`anat+orig`, `anat+orig[2]`) are no file themselves.
        if !path.exists() && afni_dataset::has_afni_name(path) {
            return Ok(Self::Afni);
        }
        if check_file_or_folder(path)?.is_dir() {
            return Ok(if ngff::looks_like_zarr(path) { Self::OmeZarr } else { Self::Dicom });
        }
        // Lowercased above, so the comparisons below are case-insensitive.
        let name = path.file_name().map(|n| n.to_string_lossy().to_ascii_lowercase()).unwrap_or_default();
        // A `.hdr` or `.img` with its other half beside it is a NIfTI pair; without it, the content decides (a
        // MetaImage may be named `.img`), and the missing half is the error when nothing else fits.
        let pair = nifti::pair_paths(path);
        if name.ends_with(".nii") || name.ends_with(".nii.gz") || matches!(pair, Ok(Some(_))) {
            return Ok(Self::Nifti);
        }
        if name.ends_with(".nrrd") || name.ends_with(".nhdr") {
            return Ok(Self::Nrrd);
        }
        if name.ends_with(".dcm") {
            return Ok(Self::Dicom);
        }
        if name.ends_with(".mha") || name.ends_with(".mhd") {
            return Ok(Self::MetaImage);
        }
        if mgh::has_mgh_name(path) {
            return Ok(Self::Mgh);
        }
        if minc::has_minc_name(path) {
            return Ok(Self::Minc);
        }
        if afni_dataset::has_afni_name(path) {
            return Ok(Self::Afni);
        }
        let mut head = [0u8; 132];
        let mut f = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
        let n = read_up_to(&mut f, &mut head).map_err(|e| Error::io(path, e))?;
        let head = &head[..n];
        if head.starts_with(b"NRRD") {
            Ok(Self::Nrrd)
        } else if files::has_dicom_preamble(head) {
            Ok(Self::Dicom)
        } else if head.starts_with(&[0x1f, 0x8b]) || nifti::looks_like_nifti(head) {
            Ok(Self::Nifti)
        } else if metaimage::looks_like_metaimage(head) {
            Ok(Self::MetaImage)
        } else if minc::looks_like_minc1(head) {
            Ok(Self::Minc)
        } else {
            pair.and(Err(Error::unsupported(
                path,
                "unknown file format (expected NIfTI, NRRD, MetaImage, MGH, MINC, AFNI (.HEAD/.BRIK) or DICOM)",
            )))
        }
    }
}

/// Reads the volume at `path` with default options. Same as `LoadOptions::new().open(path)`.
pub fn open(path: impl AsRef<Path>) -> Result<Volume> {
    LoadOptions::new().open(path)
}

impl LoadOptions<'_> {
    /// Reads the volume at `path` (a file or a DICOM series folder).
    pub fn open(&mut self, path: impl AsRef<Path>) -> Result<Volume> {
        let path = path.as_ref();
        let format = Format::detect(path)?;
        self.check_part_applies(path, format)?;
        let mut volume = match format {
            Format::Nifti => nifti::read(path, self),
            Format::Nrrd => nrrd::read(path, self),
            Format::Dicom if path.is_dir() => dicom::read_folder(path, self),
            Format::Dicom => dicom::read_files(&[path.to_path_buf()], self),
            Format::MetaImage => metaimage::read(path, self),
            Format::Mgh => mgh::read(path, self),
            Format::Minc => minc::read(path, self),
            Format::OmeZarr => ngff::read(path, self),
            Format::Afni => afni_dataset::read(path, self),
        }?;
        // Every format's volume gets the same geometry warnings (a reader that sets its own metadata keeps them).
        volume.note_geometry_warnings();
        Ok(volume)
    }

    /// Refuses a choice the file has nothing to choose from: a series of anything but DICOM, or a frame past the
    /// first of a format that holds one volume (NRRD, DICOM), which would otherwise read the whole file unasked.
    fn check_part_applies(&self, path: &Path, format: Format) -> Result<()> {
        if self.series_instance_uid.is_some() && format != Format::Dicom {
            return Err(Error::invalid(
                path,
                "a DICOM series was chosen, but this is not DICOM: a series is chosen in a DICOM folder",
            ));
        }
        match (self.frame, format) {
            (Some(t @ 1..), Format::Nrrd | Format::Dicom) => {
                Err(Error::invalid(path, format!("frame {t} is out of range: the file has 1 frame")))
            }
            _ => Ok(()),
        }
    }
}

/// Writes `volume` in the format its name says: NIfTI-1 for `.nii` and `.nii.gz` ([`nifti::write`]), NRRD for `.nrrd`
/// ([`nrrd::write`]), MetaImage for `.mha` and `.mhd` ([`metaimage::write`]), FreeSurfer MGH for `.mgh`, `.mgz` and
/// `.mgh.gz` ([`mgh::write`]), MINC 2 for `.mnc` ([`minc::write()`]), an OME-Zarr 0.5 folder for `.zarr` and
/// `.ome.zarr` ([`ngff::write()`]); any other name is an error that lists these. Atomic, as every writer.
pub fn write_volume(path: &Path, volume: &Volume) -> Result<()> {
    match VolumeFileKind::of(path) {
        Some(VolumeFileKind::Nifti) => nifti::write(path, volume),
        Some(VolumeFileKind::Nrrd) => nrrd::write(path, volume),
        Some(VolumeFileKind::MetaImage) => metaimage::write(path, volume),
        Some(VolumeFileKind::Mgh) => mgh::write(path, volume),
        Some(VolumeFileKind::Minc) => minc::write(path, volume),
        Some(VolumeFileKind::OmeZarr) => ngff::write(path, volume),
        None => Err(Error::unsupported(path, VolumeFileKind::EXPECTED)),
    }
}

/// The volume formats [`write_volume`] writes, by the output's name.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum VolumeFileKind {
    /// `.nii`, `.nii.gz`.
    Nifti,
    /// `.nrrd` (attached, gzip).
    Nrrd,
    /// `.mha`, `.mhd`.
    MetaImage,
    /// `.mgh`, `.mgz` (gzip), `.mgh.gz`.
    Mgh,
    /// `.mnc`: MINC 2.
    Minc,
    /// `.ome.zarr`, `.zarr`: an OME-Zarr 0.5 folder.
    OmeZarr,
}

impl VolumeFileKind {
    /// What a volume output may be named, for messages.
    pub const EXPECTED: &str = "a volume is written as NIfTI (.nii, .nii.gz), NRRD (.nrrd), \
         MetaImage (.mha, or .mhd with a .raw), FreeSurfer MGH (.mgh, .mgz), MINC 2 (.mnc) or OME-Zarr (a folder \
         named .ome.zarr)";

    /// The format `path`'s name says (case ignored), if it is one [`write_volume`] writes.
    #[must_use]
    #[allow(clippy::case_sensitive_file_extension_comparisons, reason = "the name is lowercased first")]
    pub fn of(path: &Path) -> Option<Self> {
        let name = path.file_name()?.to_string_lossy().to_ascii_lowercase();
        if name.ends_with(".nii") || name.ends_with(".nii.gz") {
            Some(Self::Nifti)
        } else if name.ends_with(".nrrd") {
            Some(Self::Nrrd)
        } else if name.ends_with(".mha") || name.ends_with(".mhd") {
            Some(Self::MetaImage)
        } else if mgh::has_mgh_name(path) {
            Some(Self::Mgh)
        } else if name.ends_with(".mnc") {
            Some(Self::Minc)
        } else if name.ends_with(".zarr") {
            Some(Self::OmeZarr)
        } else {
            None
        }
    }
}
