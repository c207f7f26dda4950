//! The four flavours of displacement-field files ([`FieldFormat`]), what a field was read from, and reading a file of
//! any flavour told apart by its first bytes ([`read_flavoured`]); [`super`] adds elastix's parameter files.

use std::path::Path;

use crate::error::{Error, Result};
use crate::nifti::{self, DisplacementField, NiftiFieldKind, NiftiVectorIntent};
use crate::nrrd::field::{self as nrrd_field, NrrdFieldType};

/// A displacement-field flavour (module docs).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum FieldFormat {
    /// NIfTI, intent `DISPVECT` (1006), RAS vectors: ITK ≥ 5.3 and 3D Slicer.
    Itk,
    /// NIfTI, intent `VECTOR` (1007), LPS vectors: ANTs.
    Ants,
    /// NRRD, `kinds: vector domain domain domain`, LPS vectors: 3D Slicer.
    Nrrd,
    /// MetaImage, three channels, LPS vectors: elastix's transformix and every ITK.
    MetaImage,
    /// An MNI transform file (`.xfm`) of one `Grid_Transform`, its vectors in a MINC 2 file beside it: minc-toolkit
    /// (`mincresample -transformation`) and ITK's MINC transform reader.
    Minc,
    /// An OME-Zarr 0.6 field store (a folder named `.ome.zarr`): RFC-5's `displacements`, as ngff-zarr writes it.
    Ngff,
    /// AFNI's `3dQwarp` warp saved as NIfTI: an (X, Y, Z, 1, 3) float32 array of LPS (DICOM) vectors, no intent, AFNI's
    /// extension labelling the sub-bricks `x_delta`, `y_delta`, `z_delta` (`3dNwarpApply -nwarp`). Read from an AFNI
    /// dataset (`.HEAD`/`.BRIK`) too.
    Afni,
}

impl FieldFormat {
    /// Every flavour, in the order the CLI lists them.
    pub const ALL: [Self; 7] = [Self::Itk, Self::Ants, Self::Nrrd, Self::MetaImage, Self::Minc, Self::Ngff, Self::Afni];

    /// The flavour's name on the command line and in JSON: `itk`, `ants`, `nrrd`, `metaimage`, `minc`, `ngff`, `afni`.
    #[must_use]
    pub const fn name(self) -> &'static str {
        match self {
            Self::Itk => "itk",
            Self::Ants => "ants",
            Self::Nrrd => "nrrd",
            Self::MetaImage => "metaimage",
            Self::Minc => "minc",
            Self::Ngff => "ngff",
            Self::Afni => "afni",
        }
    }

    /// The container the name of `path` implies: `Some(Nrrd)` for `.nrrd` / `.nhdr`, `Some(MetaImage)` for `.mha` /
    /// `.mhd`, `Some(Itk)` for `.nii` / `.nii.gz` (NIfTI, which is `itk` or `ants`: see [`Self::container_matches`]),
    /// `Some(Minc)` for `.xfm`, `Some(Ngff)` for `.zarr` (`.ome.zarr`), `None` for any other name.
    #[must_use]
    #[allow(clippy::case_sensitive_file_extension_comparisons, reason = "the name is lowercased first")]
    pub fn from_extension(path: &Path) -> Option<Self> {
        let name = path.file_name()?.to_string_lossy().to_ascii_lowercase();
        if name.ends_with(".nrrd") || name.ends_with(".nhdr") {
            Some(Self::Nrrd)
        } else if name.ends_with(".mha") || name.ends_with(".mhd") {
            Some(Self::MetaImage)
        } else if name.ends_with(".nii") || name.ends_with(".nii.gz") {
            Some(Self::Itk)
        } else if name.ends_with(".xfm") {
            Some(Self::Minc)
        } else if name.ends_with(".zarr") {
            Some(Self::Ngff)
        } else {
            None
        }
    }

    /// Whether a file named `path` can hold this flavour: NIfTI names for `itk`, `ants` and `afni`, NRRD names for `nrrd`,
    /// MetaImage names for `metaimage`; any other name fits every flavour but `metaimage`, whose writer needs the name
    /// to know whether its data are detached.
    #[must_use]
    pub fn container_matches(self, path: &Path) -> bool {
        match Self::from_extension(path) {
            None => matches!(self, Self::Itk | Self::Ants | Self::Nrrd),
            Some(Self::Minc) => self == Self::Minc,
            Some(Self::Ngff) => self == Self::Ngff,
            Some(Self::Itk | Self::Ants) => matches!(self, Self::Itk | Self::Ants | Self::Afni),
            Some(container) => self == container,
        }
    }

    /// The names a file of this flavour takes, for messages.
    pub(super) const fn names(self) -> &'static str {
        match self {
            Self::Itk | Self::Ants | Self::Afni => "a .nii or .nii.gz name",
            Self::Nrrd => "a .nrrd name",
            Self::MetaImage => "a .mha name (or .mhd, with a .raw data file beside it)",
            Self::Minc => "a .xfm name (its grid is written beside it, NAME_grid_0.mnc)",
            Self::Ngff => "a folder named .ome.zarr",
        }
    }
}

impl std::fmt::Display for FieldFormat {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// Which map a displacement field samples.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum FieldDirection {
    /// D(x) = u(x) − x on the output (fixed) grid, u = moving_from_fixed: ITK's resampling convention.
    #[default]
    Pullback,
    /// D(y) = d(y) − y on the moving grid, d = fixed_from_moving: a point y of the moving volume moves to y + D(y).
    Forward,
}

impl FieldDirection {
    /// `pullback` or `forward`.
    #[must_use]
    pub const fn name(self) -> &'static str {
        match self {
            Self::Pullback => "pullback",
            Self::Forward => "forward",
        }
    }
}

impl std::fmt::Display for FieldDirection {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// What a field was read from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FieldSource {
    /// A displacement field file of a flavour.
    Field(FieldFormat),
    /// An elastix transform parameter file, sampled on its fixed grid as transformix does.
    ElastixTransform,
    /// An ITK HDF5 transform file (`.h5`) holding a displacement field, with the transforms around it, sampled on
    /// that field's grid, or B-splines sampled on the grid a command gives ([`crate::itk_h5::read_field_on`]).
    ItkHdf5,
    /// An ITK text transform file (`.tfm`) holding B-splines, with the affines around them, sampled on the grid a
    /// command gives ([`crate::itk_chain::ItkChain::field_on`]).
    ItkTransform,
    /// A DICOM Deformable Spatial Registration's grid of vectors ([`crate::dicom_reg::read_field`]).
    DicomRegistration,
    /// A Learn2Reg `.npz`, read against the fixed and moving grids ([`crate::learn2reg::pullback_from_voxels`]).
    Learn2Reg,
    /// An FSL FNIRT warp, read against its reference (the fixed grid) and input ([`crate::fnirt::read_pullback`]).
    Fnirt,
}

impl FieldSource {
    /// How reports name it: the flavour's name (`itk`, `ants`, `nrrd`, `metaimage`, `minc`, `ngff`, `afni`), or
    /// `elastix`, `itk_h5`, `itk_tfm`, `dicom`, `learn2reg`, `fnirt`. (`minc` is an MNI transform file's grid; `afni` is
    /// read from a NIfTI file or an AFNI dataset.)
    #[must_use]
    pub const fn name(self) -> &'static str {
        match self {
            Self::Field(format) => format.name(),
            Self::ElastixTransform => "elastix",
            Self::ItkHdf5 => "itk_h5",
            Self::ItkTransform => "itk_tfm",
            Self::DicomRegistration => "dicom",
            Self::Learn2Reg => "learn2reg",
            Self::Fnirt => "fnirt",
        }
    }
}

/// What [`super::read_field_info`] found.
#[derive(Clone, Debug, PartialEq)]
pub struct ReadField {
    /// The grid and the vectors, LPS.
    pub field: DisplacementField,
    pub source: FieldSource,
    /// The direction the file states, where it can: a NRRD field's `displacement field type` (resampling is the
    /// pull-back, modeling the forward map); `None` when the file says nothing (NIfTI never does; readers then take
    /// it as a pull-back, ITK's convention).
    pub direction: Option<FieldDirection>,
    /// What the reader assumed where the file is silent (an OME-Zarr field's axes without a unit, say), for the user
    /// to see.
    pub warnings: Vec<String>,
}

/// The first bytes of the regular file `path` (up to 132: a DICOM file's preamble and `DICM`), to tell its kind by.
pub(crate) fn head(path: &Path) -> Result<Vec<u8>> {
    crate::files::check_regular_file(path)?;
    let mut head = [0u8; 132];
    let mut f = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let n = crate::files::read_up_to(&mut f, &mut head).map_err(|e| Error::io(path, e))?;
    Ok(head[..n].to_vec())
}

/// Reads the field file `path` of one of the four flavours, told apart by its first bytes `head` (module docs of
/// [`super`]): `None` when the bytes are none of NRRD, MetaImage and NIfTI.
pub(crate) fn read_flavoured(path: &Path, head: &[u8]) -> Result<Option<ReadField>> {
    if head.starts_with(b"NRRD") {
        let (field, kind) = nrrd_field::read_displacement_field(path)?;
        let direction = kind.map(|k| match k {
            NrrdFieldType::Resampling => FieldDirection::Pullback,
            NrrdFieldType::Modeling => FieldDirection::Forward,
        });
        return Ok(Some(ReadField {
            field,
            source: FieldSource::Field(FieldFormat::Nrrd),
            direction,
            warnings: Vec::new(),
        }));
    }
    if crate::metaimage::looks_like_metaimage(head) {
        let field = crate::metaimage::read_displacement_field(path)?;
        return Ok(Some(ReadField {
            field,
            source: FieldSource::Field(FieldFormat::MetaImage),
            direction: None,
            warnings: Vec::new(),
        }));
    }
    if head.starts_with(&[0x1f, 0x8b]) || nifti::looks_like_nifti(head) {
        let (field, kind) = nifti::read_vector_field(path)?;
        // ITK's and ANTs' files do not say which map they sample (a pull-back, as ITK takes them); AFNI's warp is
        // always 3dNwarpApply's pull-back.
        let (source, direction) = match kind {
            NiftiFieldKind::Intent(NiftiVectorIntent::DispvectRas) => (FieldSource::Field(FieldFormat::Itk), None),
            NiftiFieldKind::Intent(NiftiVectorIntent::VectorLps) => (FieldSource::Field(FieldFormat::Ants), None),
            NiftiFieldKind::AfniWarp => (FieldSource::Field(FieldFormat::Afni), Some(FieldDirection::Pullback)),
        };
        return Ok(Some(ReadField { field, source, direction, warnings: Vec::new() }));
    }
    Ok(None)
}

/// A grid to sample a transform on that gives none of its own (ITK's B-spline): the fixed volume's, where a command
/// has one.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SampleGrid {
    pub dims: [usize; 3],
    pub lps_from_index: crate::geometry::Transform<crate::geometry::Lps, crate::geometry::Index>,
    /// Where the grid's geometry came from (the volume's), which the sampled field keeps.
    pub geometry_source: crate::volume::GeometrySource,
}

impl SampleGrid {
    /// The grid of `volume`.
    #[must_use]
    pub fn of(volume: &crate::Volume) -> Self {
        Self { dims: volume.dims, lps_from_index: volume.lps_from_index, geometry_source: volume.geometry_source }
    }
}
