//! `warpbench info <file-or-dir> [--json]`: dims, spacing, `lps_from_index`, where the geometry came
//! from, sample type, value range, modality and series of a volume; for a displacement field (any flavour `warp
//! --field` reads), its flavour, direction, grid and largest displacement; for an ITK transform file (`.tfm`, `.h5`,
//! `.mat`) without a field, the transforms it holds and how warpbench takes it. With `--json` the output follows
//! the `warpbench-info/1` schema documented in `docs/cli.md`.

use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::Context;
use serde::Serialize;
use sha2::{Digest, Sha256};
use warpbench_io::{ErrorKind, Format, GeometrySource, LoadOptions, Modality, SeriesSummary, Volume, VoxelData};

use crate::exit::Failure;
use crate::progress::Bar;

/// What `warpbench info --help` says above the options; its first paragraph is the summary that `-h` and
/// `warpbench --help` show.
const HELP: &str = "\
Print what a volume holds: dims, spacing, lps_from_index, geometry source, dtype, value range,
modality and series.

Reads NIfTI-1/2 (.nii, .nii.gz, or a .hdr/.img pair), NRRD (.nrrd, .nhdr), MetaImage (.mha, .mhd),
FreeSurfer's MGH (.mgh, .mgz), MINC 1 or 2 (.mnc, .mnc.gz), an AFNI dataset (.HEAD with its .BRIK or .BRIK.gz),
a DICOM series folder or one DICOM file. A folder with several series lists them. A displacement field (any flavour
warp --field reads, an ITK .h5 holding one, a DICOM Deformable Spatial Registration, Learn2Reg's .npz, AFNI's
3dQwarp warp) is described as a field: its flavour, the direction
it states, its grid and its largest displacement. An ITK transform file (.tfm, .h5, ANTs' .mat) is described by the
transforms it holds and how warpbench takes it (--initial, --field or --landmarks). Example:

    warpbench info tests/data/nifti/ch2.nii.gz --json";

/// The arguments of `warpbench info`.
#[derive(Clone, Debug, Default, clap::Args)]
#[command(about = crate::args::summary(HELP), long_about = HELP)]
pub struct InfoArgs {
    /// A volume file or a DICOM series folder.
    pub path: PathBuf,
    /// Machine-readable output (schema warpbench-info/1, see docs/cli.md).
    #[arg(long)]
    pub json: bool,
    /// For a 4-D NIfTI or MetaImage: the frame (t index) to read.
    #[arg(long)]
    pub frame: Option<usize>,
    /// For a folder with several DICOM series: the SeriesInstanceUID to read.
    #[arg(long)]
    pub series: Option<String>,
    /// No progress bar.
    #[arg(long, short)]
    pub quiet: bool,
}

/// The `--json` document, schema `warpbench-info/1`.
#[derive(Debug, Serialize)]
pub struct InfoJson {
    pub schema: &'static str,
    pub path: String,
    #[serde(flatten)]
    pub content: InfoContent,
}

/// What `info` found: one volume, or a folder of several DICOM series to choose from.
#[derive(Debug, Serialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum InfoContent {
    Volume(Box<VolumeInfo>),
    SeriesList { series: Vec<SeriesSummary> },
    DisplacementField(Box<FieldInfo>),
    Transform(Box<TransformInfo>),
}

/// A transform file's description: what an ITK `.tfm`, an `.h5` without a displacement field, ANTs' `.mat`, FSL's
/// FLIRT matrix, AFNI's matrix file or FreeSurfer's LTA holds.
#[derive(Debug, Serialize)]
pub struct TransformInfo {
    /// `itk_tfm`, `itk_h5`, `ants_mat`, `fsl` for FSL's FLIRT matrix, `afni` for AFNI's matrix file, `mni_xfm` for an
    /// MNI transform file of linear transforms, or `lta` for
    /// FreeSurfer's LTA.
    pub format: &'static str,
    /// The transforms in the file's order (a composite's members; ITK applies the last one first).
    pub transforms: Vec<TransformMember>,
    /// How warpbench takes the file.
    pub read_as: ReadAs,
    /// An LTA's type and volumes; null for the other formats.
    pub lta: Option<LtaVolumes>,
}

/// What an LTA says of itself: its type and the volumes it maps from (src) and to (dst).
#[derive(Debug, Serialize)]
pub struct LtaVolumes {
    /// `LINEAR_VOX_TO_VOX` or `LINEAR_RAS_TO_RAS`.
    #[serde(rename = "type")]
    pub kind: &'static str,
    /// The src volume's file as FreeSurfer noted it (`""` when it noted none), null without valid volume info.
    pub src: Option<String>,
    /// The dst volume's, likewise.
    pub dst: Option<String>,
}

/// One transform of a file.
#[derive(Debug, Serialize)]
pub struct TransformMember {
    pub kind: MemberKind,
    /// Control points per axis of a B-spline, voxels of a field's grid; null for an affine and a thin-plate spline.
    pub size: Option<[usize; 3]>,
    /// The landmarks of a thin-plate spline; null for the others.
    pub landmarks: Option<usize>,
}

/// What one transform of a file is, as warpbench reads it (ITK's linear classes are all affines to it).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum MemberKind {
    Affine,
    Bspline,
    ThinPlateSpline,
    DisplacementField,
    /// 3D Slicer's `InverseBSplineTransform`: the inverse of the B-spline its numbers describe.
    InverseBspline,
    /// 3D Slicer's `InverseDisplacementFieldTransform`.
    InverseDisplacementField,
}

/// How warpbench takes a transform file.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum ReadAs {
    /// Linear transforms only: `--initial`, the window's starting transform.
    StartingTransform,
    /// A chain with a B-spline or a field: `--field`, `--initial-field`, the window's field under the landmarks.
    DisplacementField,
    /// A thin-plate spline alone: its landmarks, as pairs (`--landmarks`).
    Landmarks,
}

impl TransformInfo {
    /// The ITK transform file at `path` (`None` when it is not one warpbench reads).
    fn read(path: &Path) -> Option<Self> {
        use std::io::Read as _;
        use warpbench_io::itk_chain::{InverseStep, ItkStep};
        use warpbench_io::itk_tfm::ItkTransform;
        let member = |kind, size, landmarks| TransformMember { kind, size, landmarks };
        // Each reader refuses what is not a regular file first (a named pipe would block the opening below).
        for (format, read) in [("fsl", warpbench_io::fsl::read as Reader), ("afni", warpbench_io::afni::read)] {
            if read(path).is_ok() {
                let transforms = vec![member(MemberKind::Affine, None, None)];
                return Some(Self { format, transforms, read_as: ReadAs::StartingTransform, lta: None });
            }
        }
        if let Ok(lta) = warpbench_io::lta::read(path) {
            let file = |v: &Option<warpbench_io::lta::VolumeInfo>| v.as_ref().map(|v| v.filename.clone());
            let lta = LtaVolumes { kind: lta.kind.code_and_name().1, src: file(&lta.src), dst: file(&lta.dst) };
            let transforms = vec![member(MemberKind::Affine, None, None)];
            return Some(Self { format: "lta", transforms, read_as: ReadAs::StartingTransform, lta: Some(lta) });
        }
        if let Ok(steps) = warpbench_io::mni_xfm::read(path) {
            use warpbench_io::mni_xfm::XfmStep;
            // A grid transform is described as the field it is (FieldInfo); a thin-plate spline is not read.
            if !steps.iter().all(|s| matches!(s, XfmStep::Linear(_))) {
                return None;
            }
            let transforms = steps.iter().map(|_| member(MemberKind::Affine, None, None)).collect();
            return Some(Self { format: "mni_xfm", transforms, read_as: ReadAs::StartingTransform, lta: None });
        }
        let chain = warpbench_io::transform_file::read_chain(path).ok()?;
        let mut head = Vec::new();
        std::fs::File::open(path).ok()?.take(64).read_to_end(&mut head).ok()?;
        let format = if warpbench_io::itk_h5::looks_like_hdf5(&head) {
            "itk_h5"
        } else if warpbench_io::itk_tfm::looks_like_text(&head) {
            "itk_tfm"
        } else {
            "ants_mat"
        };
        let transforms: Vec<TransformMember> = chain
            .steps
            .iter()
            .map(|step| match step {
                ItkStep::Transform(ItkTransform::Affine(_)) => member(MemberKind::Affine, None, None),
                ItkStep::Transform(ItkTransform::BSpline(b)) => member(MemberKind::Bspline, Some(b.grid_size), None),
                ItkStep::Transform(ItkTransform::ThinPlateSpline(t)) => {
                    member(MemberKind::ThinPlateSpline, None, Some(t.source_lps.len()))
                }
                ItkStep::Field(f) => member(MemberKind::DisplacementField, Some(f.field.dims), None),
                ItkStep::Inverse(InverseStep::BSpline(b)) => {
                    member(MemberKind::InverseBspline, Some(b.grid_size), None)
                }
                ItkStep::Inverse(InverseStep::Field(f)) => {
                    member(MemberKind::InverseDisplacementField, Some(f.field.dims), None)
                }
            })
            .collect();
        let read_as = if transforms.iter().all(|t| t.kind == MemberKind::Affine) {
            ReadAs::StartingTransform
        } else if transforms.iter().any(|t| t.kind == MemberKind::ThinPlateSpline) {
            ReadAs::Landmarks
        } else {
            ReadAs::DisplacementField
        };
        Some(Self { format, transforms, read_as, lta: None })
    }
}

/// A reader of a matrix file that needs the two volumes.
type Reader = fn(&Path) -> warpbench_io::Result<nalgebra::Matrix4<f64>>;

/// A displacement field's description.
#[derive(Debug, Serialize)]
pub struct FieldInfo {
    /// `itk`, `ants`, `nrrd`, `metaimage`, `minc`, `ngff`, `elastix`, `itk_h5`, `dicom` or `learn2reg`.
    pub format: &'static str,
    /// `pullback` or `forward` where the file says (NRRD, `.h5`, DICOM, Learn2Reg), else null (NIfTI, which readers
    /// take as a pull-back).
    pub direction: Option<&'static str>,
    pub dims: [usize; 3],
    /// `mm`, or `voxels` for Learn2Reg's steps, which have no grid of their own.
    pub units: &'static str,
    /// The grid's spacing and row-major `lps_from_index`, as for a volume; null for Learn2Reg's.
    pub spacing_mm: Option<[f64; 3]>,
    pub lps_from_index: Option<[[f64; 4]; 4]>,
    pub geometry_source: Option<GeometrySourceJson>,
    /// The largest |D| over the grid, in `units`.
    pub max_displacement: f64,
    /// What the reader assumed where the file is silent (an OME-Zarr field's axes without a unit, say).
    pub warnings: Vec<String>,
}

impl FieldInfo {
    /// The field at `path` when it is one (`None` when no field reader takes it); an `.npz`, which only Learn2Reg's
    /// reader takes, with that reader's refusal; an FSL FNIRT file as far as it can be told without its images.
    fn read(path: &Path) -> Result<Option<Self>, Failure> {
        let largest = |vectors: &[[f32; 3]]| {
            vectors.iter().map(|d| d.iter().map(|&c| f64::from(c).powi(2)).sum::<f64>().sqrt()).fold(0.0, f64::max)
        };
        if path.is_file() && warpbench_io::learn2reg::is_npz_file(path)? {
            let steps = warpbench_io::learn2reg::read_voxel_field(path)?;
            return Ok(Some(Self {
                format: "learn2reg",
                direction: Some("pullback"),
                dims: steps.dims,
                units: "voxels",
                spacing_mm: None,
                lps_from_index: None,
                geometry_source: None,
                max_displacement: largest(&steps.steps_vox),
                warnings: Vec::new(),
            }));
        }
        if crate::project::field_file::is_fnirt_file(path)? {
            let summary = warpbench_io::fnirt::summary(path)?;
            return Ok(Some(Self {
                format: "fnirt",
                direction: Some("pullback"),
                dims: summary.dims,
                units: "mm",
                spacing_mm: summary.lps_from_index.as_ref().map(|(t, _)| warpbench_io::geometry::spacing_mm(t)),
                lps_from_index: summary.lps_from_index.as_ref().map(|(t, _)| t.rows()),
                geometry_source: summary.lps_from_index.map(|(_, source)| source.into()),
                max_displacement: summary.max_displacement_mm,
                warnings: summary.notes,
            }));
        }
        let Ok(read) = warpbench_io::displacement::read_field_info(path) else { return Ok(None) };
        let f = &read.field;
        Ok(Some(Self {
            format: read.source.name(),
            direction: read.direction.map(warpbench_io::displacement::FieldDirection::name),
            dims: f.dims,
            units: "mm",
            spacing_mm: Some(warpbench_io::geometry::spacing_mm(&f.lps_from_index)),
            lps_from_index: Some(f.lps_from_index.rows()),
            geometry_source: Some(f.geometry_source.into()),
            max_displacement: largest(&f.displacements_lps),
            warnings: read.warnings.clone(),
        }))
    }
}

/// One volume's description.
#[derive(Debug, Serialize)]
pub struct VolumeInfo {
    pub format: &'static str,
    pub dims: [usize; 3],
    pub spacing_mm: [f64; 3],
    /// Row-major 4×4: LPS mm = M · (i, j, k, 1), index 0 at the centre of the first voxel.
    pub lps_from_index: [[f64; 4]; 4],
    pub geometry_source: GeometrySourceJson,
    pub dtype: &'static str,
    /// [min, max] of the finite samples (after rescale), or null when there is none.
    pub value_range: Option<[f64; 2]>,
    /// "CT", "MR", another DICOM modality code, or null.
    pub modality: Option<String>,
    pub rescale: RescaleJson,
    pub value_units: Option<String>,
    pub series_instance_uid: Option<String>,
    pub study_instance_uid: Option<String>,
    pub series_number: Option<i64>,
    pub description: Option<String>,
    pub warnings: Vec<String>,
    /// sha256 of the samples as little-endian `dtype`, i fastest: equal to what an independent
    /// reader gets from `numpy.asarray(v, '<dtype').tobytes(order='F')`.
    pub voxel_sha256: String,
}

#[derive(Debug, Serialize)]
pub struct GeometrySourceJson {
    /// One of sform, qform, pixdim, dicom, nrrd_space, nrrd_spacings, metaimage, assumed.
    pub kind: &'static str,
    /// The NIfTI sform/qform code, when there is one.
    pub code: Option<i32>,
}

#[derive(Debug, Serialize)]
pub struct RescaleJson {
    pub slope: f64,
    pub intercept: f64,
    pub applied: bool,
}

impl From<GeometrySource> for GeometrySourceJson {
    fn from(g: GeometrySource) -> Self {
        let (kind, code) = match g {
            GeometrySource::NiftiSform { code } => ("sform", Some(code)),
            GeometrySource::NiftiQform { code } => ("qform", Some(code)),
            GeometrySource::NiftiPixdim => ("pixdim", None),
            GeometrySource::DicomPatient => ("dicom", None),
            GeometrySource::NrrdSpace => ("nrrd_space", None),
            GeometrySource::NrrdSpacings => ("nrrd_spacings", None),
            GeometrySource::MetaImage => ("metaimage", None),
            GeometrySource::Mgh => ("mgh", None),
            GeometrySource::Minc => ("minc", None),
            GeometrySource::OmeZarr => ("ome-zarr", None),
            GeometrySource::Afni => ("afni", None),
            GeometrySource::ElastixParameters => ("elastix", None),
            GeometrySource::ItkTransformFile => ("itk_transform", None),
            GeometrySource::Learn2RegFixedImage => ("learn2reg_fixed_image", None),
            GeometrySource::FnirtReferenceImage => ("fnirt_reference_image", None),
            GeometrySource::Assumed => ("assumed", None),
        };
        Self { kind, code }
    }
}

fn modality_code(m: &Modality) -> Option<String> {
    match m {
        Modality::Ct => Some("CT".into()),
        Modality::Mr => Some("MR".into()),
        Modality::Other(s) => Some(s.clone()),
        Modality::Unknown => None,
    }
}

fn format_name(f: Format) -> &'static str {
    match f {
        Format::Nifti => "nifti",
        Format::Nrrd => "nrrd",
        Format::Dicom => "dicom",
        Format::MetaImage => "metaimage",
        Format::Mgh => "mgh",
        Format::Minc => "minc",
        Format::OmeZarr => "ome-zarr",
        Format::Afni => "afni",
    }
}

impl VolumeInfo {
    #[must_use]
    pub fn new(format: Format, v: &Volume) -> Self {
        Self {
            format: format_name(format),
            dims: v.dims,
            spacing_mm: v.spacing_mm(),
            lps_from_index: v.lps_from_index.rows(),
            geometry_source: v.geometry_source.into(),
            dtype: v.sample_type().name(),
            value_range: v.data.finite_range().map(|(a, b)| [a, b]),
            modality: modality_code(&v.modality),
            rescale: RescaleJson { slope: v.rescale.slope, intercept: v.rescale.intercept, applied: v.rescale.applied },
            value_units: v.metadata.value_units.clone(),
            series_instance_uid: v.metadata.series_instance_uid.clone(),
            study_instance_uid: v.metadata.study_instance_uid.clone(),
            series_number: v.metadata.series_number,
            description: v.metadata.description.clone(),
            warnings: v.metadata.warnings.clone(),
            voxel_sha256: voxel_sha256(&v.data),
        }
    }
}

/// sha256 of the samples as little-endian bytes, hashed a chunk at a time (no copy of a large volume).
fn voxel_sha256(data: &VoxelData) -> String {
    let mut hasher = Sha256::new();
    data.for_each_le_chunk(|bytes| hasher.update(bytes));
    hex::encode(hasher.finalize())
}

/// A reader's error in the words of this command: a 4-D file's frame is chosen with `--frame`.
fn cli_error(e: warpbench_io::Error) -> Failure {
    match e.kind {
        ErrorKind::FrameRequired { frames } if warpbench_io::afni_dataset::has_afni_name(&e.path) => {
            Failure::BadInput(anyhow::anyhow!(
                "{}: an AFNI dataset of {frames} sub-bricks: choose one with --frame N (N from 0 to {})",
                e.path.display(),
                frames.saturating_sub(1)
            ))
        }
        ErrorKind::FrameRequired { frames } => {
            // Three frames may be Learn2Reg's field, whose NIfTI form is an (X, Y, Z, 3) array: say where it is read.
            let field = if frames == 3 {
                "; if it is Learn2Reg's displacement field (steps in voxels), warp, render and field read it with \
                 --field-format learn2reg"
            } else {
                ""
            };
            Failure::BadInput(anyhow::anyhow!(
                "{}: 4-D file with {frames} frames: choose one with --frame N (N from 0 to {}){field}",
                e.path.display(),
                frames.saturating_sub(1)
            ))
        }
        _ => e.into(),
    }
}

/// Loads `opts.path` and describes it.
pub fn inspect(opts: &InfoArgs) -> Result<InfoJson, Failure> {
    let path = &opts.path;
    let described = |content| Ok(InfoJson { schema: "warpbench-info/1", path: path.display().to_string(), content });
    let format = match Format::detect(path) {
        Ok(format) => format,
        Err(e) => {
            if let Some(field) = FieldInfo::read(path)? {
                return described(InfoContent::DisplacementField(Box::new(field)));
            }
            return match TransformInfo::read(path) {
                Some(transform) => described(InfoContent::Transform(Box::new(transform))),
                None => Err(e.into()),
            };
        }
    };
    let mut bar = Bar::new(opts.quiet);
    let mut load = LoadOptions::new().progress(|p| bar.update(p));
    load.frame = opts.frame;
    load.series_instance_uid.clone_from(&opts.series);
    let loaded = load.open(path);
    drop(load);
    bar.finish();
    let content = match loaded {
        Ok(v) => InfoContent::Volume(Box::new(VolumeInfo::new(format, &v))),
        Err(e) => match e.kind {
            ErrorKind::MultipleSeries(series) => InfoContent::SeriesList { series },
            // Not a volume: a field in a volume's container (a 5-D NIfTI, a vector NRRD or MetaImage, a DICOM DSR).
            _ => match FieldInfo::read(path)? {
                Some(field) => InfoContent::DisplacementField(Box::new(field)),
                None => return Err(cli_error(e)),
            },
        },
    };
    described(content)
}

/// Runs `warpbench info`, writing to `out`. The volume's warnings also go to stderr, where they are seen
/// when `out` is a pipe or a `--json` document.
pub fn run(opts: &InfoArgs, out: &mut dyn Write) -> Result<(), Failure> {
    let info = inspect(opts)?;
    if let InfoContent::Volume(v) = &info.content {
        for w in &v.warnings {
            eprintln!("warpbench: warning: {}: {w}", info.path);
        }
    }
    let written = if opts.json {
        serde_json::to_writer_pretty(&mut *out, &info).map_err(std::io::Error::from).and_then(|()| writeln!(out))
    } else {
        write_text(&info, out)
    };
    written.context("writing the output").map_err(Failure::Internal)
}

fn fmt3(v: [f64; 3]) -> String {
    format!("{} × {} × {}", trim(v[0]), trim(v[1]), trim(v[2]))
}

/// [`trim`], or in scientific notation for a number that six decimals would round to 0 (an AFNI scale factor of
/// 3.9e-08).
fn number(x: f64) -> String {
    if x != 0.0 && x.abs() < 1e-4 { format!("{x:e}") } else { trim(x) }
}

fn trim(x: f64) -> String {
    let s = format!("{x:.6}");
    let s = s.trim_end_matches('0').trim_end_matches('.');
    if s == "-0" { "0".into() } else { s.into() }
}

fn write_text(info: &InfoJson, out: &mut dyn Write) -> std::io::Result<()> {
    writeln!(out, "{}", info.path)?;
    match &info.content {
        InfoContent::SeriesList { series } => {
            writeln!(out, "  {} DICOM series; pick one with --series UID:", series.len())?;
            for s in series {
                writeln!(out, "  - {s}")?;
            }
        }
        InfoContent::Volume(v) => write_volume(v, out)?,
        InfoContent::DisplacementField(f) => write_field(f, out)?,
        InfoContent::Transform(t) => write_transform(t, out)?,
    }
    Ok(())
}

fn write_transform(t: &TransformInfo, out: &mut dyn Write) -> std::io::Result<()> {
    let n = t.transforms.len();
    let order = if n > 1 { ", the last applied first" } else { "" };
    let count = if n == 1 { "1 transform".to_owned() } else { format!("{n} transforms") };
    if t.format == "fsl" {
        writeln!(
            out,
            "  FSL FLIRT matrix (fsl): an affine in the voxel coordinates of the two images it was made with"
        )?;
        return writeln!(
            out,
            "  read as         a starting transform (--initial), against --fixed as FLIRT's -ref and --moving as its -in"
        );
    }
    if let Some(lta) = &t.lta {
        let name = |f: &Option<String>| match f.as_deref() {
            None => "not stated".to_owned(),
            Some("") => "a volume it does not name".to_owned(),
            Some(f) => f.to_owned(),
        };
        writeln!(out, "  FreeSurfer LTA (lta), {}: an affine from src to dst", lta.kind)?;
        writeln!(out, "  src             {}", name(&lta.src))?;
        writeln!(out, "  dst             {}", name(&lta.dst))?;
        return writeln!(
            out,
            "  read as         a starting transform (--initial), between --fixed and --moving, which must be its src \
             and dst (either way round)"
        );
    }
    if t.format == "mni_xfm" {
        writeln!(
            out,
            "  MNI transform file (mni_xfm): {} linear transform(s), the moving volume's world to the fixed one's, RAS mm",
            t.transforms.len()
        )?;
        return writeln!(out, "  read as         a starting transform (--initial), the inverse of the file's map");
    }
    if t.format == "afni" {
        writeln!(out, "  AFNI matrix file (afni): an affine from the base's DICOM coordinates to the source's")?;
        return writeln!(
            out,
            "  read as         a starting transform (--initial), --fixed the base and --moving the source, neither oblique"
        );
    }
    writeln!(out, "  ITK transform file ({}), {count}{order}", t.format)?;
    for (i, m) in t.transforms.iter().enumerate() {
        let what = match m.kind {
            MemberKind::Affine => "affine",
            MemberKind::Bspline => "B-spline",
            MemberKind::ThinPlateSpline => "thin-plate spline",
            MemberKind::DisplacementField => "displacement field",
            MemberKind::InverseBspline => "inverse of a B-spline (3D Slicer's)",
            MemberKind::InverseDisplacementField => "inverse of a displacement field (3D Slicer's)",
        };
        let unit = if matches!(m.kind, MemberKind::Bspline | MemberKind::InverseBspline) {
            "control points"
        } else {
            "voxels"
        };
        let size = m.size.map(|[a, b, c]| format!(", {a} × {b} × {c} {unit}")).unwrap_or_default();
        let landmarks = m.landmarks.map(|l| format!(", {l} landmarks")).unwrap_or_default();
        writeln!(out, "    {}  {what}{size}{landmarks}", i + 1)?;
    }
    let read_as = match t.read_as {
        ReadAs::StartingTransform => "a starting transform (--initial)",
        ReadAs::DisplacementField
            if t.transforms
                .iter()
                .any(|m| matches!(m.kind, MemberKind::DisplacementField | MemberKind::InverseDisplacementField)) =>
        {
            "a displacement field (--field, --initial-field), sampled on its field's grid"
        }
        ReadAs::DisplacementField => {
            "a displacement field (--field, --initial-field); it has no grid: --field samples it on the output grid, \
             under the landmarks it acts as it is"
        }
        ReadAs::Landmarks => "landmark pairs (--landmarks)",
    };
    writeln!(out, "  read as         {read_as}")
}

fn write_field(f: &FieldInfo, out: &mut dyn Write) -> std::io::Result<()> {
    let d = f.dims;
    writeln!(
        out,
        "  displacement field ({}), {}",
        f.format,
        f.direction.unwrap_or("direction not stated: a pull-back")
    )?;
    writeln!(out, "  dims            {} × {} × {}", d[0], d[1], d[2])?;
    if let (Some(spacing), Some(m), Some(g)) = (f.spacing_mm, &f.lps_from_index, &f.geometry_source) {
        writeln!(out, "  spacing         {} mm", fmt3(spacing))?;
        writeln!(out, "  geometry from   {}", g.kind)?;
        writeln!(out, "  lps_from_index")?;
        for row in m {
            writeln!(out, "    [{:>12.6} {:>12.6} {:>12.6} {:>12.6}]", row[0], row[1], row[2], row[3])?;
        }
    } else if f.format == "fnirt" {
        writeln!(out, "  grid            none of its own: FSL's coordinates of its reference and input images")?;
    } else {
        writeln!(out, "  grid            none: steps in the voxels of the fixed and moving images")?;
    }
    writeln!(out, "  max |D|         {} {}", trim(f.max_displacement), f.units)?;
    for w in &f.warnings {
        writeln!(out, "  warning         {w}")?;
    }
    Ok(())
}

fn write_volume(v: &VolumeInfo, out: &mut dyn Write) -> std::io::Result<()> {
    let d = v.dims;
    writeln!(out, "  format          {}", v.format)?;
    writeln!(out, "  dims            {} × {} × {}", d[0], d[1], d[2])?;
    writeln!(out, "  spacing         {} mm", fmt3(v.spacing_mm))?;
    let g = &v.geometry_source;
    match g.code {
        Some(c) => writeln!(out, "  geometry from   {} (code {c})", g.kind)?,
        None => writeln!(out, "  geometry from   {}", g.kind)?,
    }
    writeln!(out, "  lps_from_index")?;
    for row in &v.lps_from_index {
        writeln!(out, "    [{:>12.6} {:>12.6} {:>12.6} {:>12.6}]", row[0], row[1], row[2], row[3])?;
    }
    writeln!(out, "  dtype           {}", v.dtype)?;
    match v.value_range {
        Some([lo, hi]) => writeln!(
            out,
            "  value range     {} .. {}{}",
            trim(lo),
            trim(hi),
            v.value_units.as_deref().map(|u| format!(" {u}")).unwrap_or_default()
        )?,
        None => writeln!(out, "  value range     (no finite samples)")?,
    }
    let r = &v.rescale;
    if r.applied {
        writeln!(out, "  rescale         value = {} × stored + {} (applied)", number(r.slope), number(r.intercept))?;
    } else {
        writeln!(out, "  rescale         none")?;
    }
    writeln!(out, "  modality        {}", v.modality.as_deref().unwrap_or("unknown"))?;
    if let Some(uid) = &v.series_instance_uid {
        let num = v.series_number.map(|n| format!(" (series {n})")).unwrap_or_default();
        writeln!(out, "  series          {uid}{num}")?;
    }
    if let Some(desc) = &v.description {
        writeln!(out, "  description     {desc}")?;
    }
    for w in &v.warnings {
        writeln!(out, "  warning         {w}")?;
    }
    Ok(())
}
