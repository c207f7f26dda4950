//! The command-line argument groups that several subcommands share (clap), one per concept, each flattened into the
//! subcommands' own `Args` structs: the volume pair ([`VolumePairArgs`], with which volume of a 4-D file or a DICOM
//! folder each side reads, [`PartArgs`]), the landmarks and the warp around them ([`PairArgs`], with the method,
//! [`MethodArgs`]), the report flags ([`ReportArgs`]) and the render settings ([`RenderSettingsArgs`]).
//!
//! This module declares flags and parses values only; [`crate::inputs`] turns the groups into the model's types
//! (`TryFrom<PairArgs>`), once, at the start of a subcommand. A subcommand that describes a shared flag in its own
//! words (what its `--fixed` is for) says so with [`help`] in a `#[command(mut_args(…))]` attribute, and its help
//! text, the `--help` page, comes from [`summary`] of one string beside its `Args` struct.

use std::path::PathBuf;

use warpbench_io::Part;

use crate::procedural::ProceduralSpec;
use crate::settings::{Blend, MethodKind, Preset, ProceduralKind, Shading, Stiffness};

/// Sets the help text of the arguments named in `texts` (`(id, text)`): for a subcommand that describes flags of a
/// shared group in its own words, as `#[command(mut_args(help(&[("fixed", "…")])))]` on its `Args` struct. (In
/// place: `Command::mut_arg` would move the argument to the end of the usage line.)
pub fn help(texts: &'static [(&'static str, &'static str)]) -> impl FnMut(clap::Arg) -> clap::Arg {
    move |arg| match texts.iter().find(|(id, _)| arg.get_id() == *id) {
        Some((_, text)) => arg.help(*text),
        None => arg,
    }
}

/// The first paragraph of a subcommand's help text (its `long_about`): what `-h` and the list of subcommands show.
#[must_use]
pub fn summary(help: &'static str) -> &'static str {
    help.split_once("\n\n").map_or(help, |(first, _)| first)
}

/// `--fixed` and `--moving`: the pair of volumes a pair subcommand reads (NIfTI, NRRD or a DICOM series folder).
/// Each subcommand describes them in its own words ([`help`]). Both are required, except where a subcommand takes
/// them from `--session` ([`or_session`]); [`crate::inputs::LandmarkWarp::volumes`] gives the files to read.
#[derive(Clone, Debug, PartialEq, Eq, clap::Args)]
pub struct VolumePairArgs {
    /// The fixed volume.
    #[arg(long, required = true)]
    pub fixed: Option<PathBuf>,
    /// The moving volume.
    #[arg(long, required = true)]
    pub moving: Option<PathBuf>,
    #[command(flatten)]
    pub parts: PartArgs,
}

/// For `#[command(mut_args(crate::args::or_session))]` on a subcommand that takes `--session`: `--fixed` and
/// `--moving` may be left out there, and the session's volumes (the files the window read) are read.
#[must_use]
pub fn or_session(arg: clap::Arg) -> clap::Arg {
    if !matches!(arg.get_id().as_str(), "fixed" | "moving") {
        return arg;
    }
    let text = arg.get_help().map_or_else(String::new, ToString::to_string);
    arg.required(false)
        .required_unless_present("session")
        .help(format!("{text}; with --session, the session's by default"))
}

/// `--fixed-frame`, `--fixed-series`, `--moving-frame` and `--moving-series`: which volume each side reads from a
/// file or folder that holds several.
#[derive(Clone, Debug, Default, PartialEq, Eq, clap::Args)]
pub struct PartArgs {
    /// The frame of a 4-D fixed file to read (NIfTI, MetaImage, MGH, MINC, OME-Zarr; an AFNI sub-brick), from 0.
    #[arg(long, value_name = "N", conflicts_with = "fixed_series")]
    pub fixed_frame: Option<usize>,
    /// The series to read from a fixed DICOM folder of several, by its SeriesInstanceUID (`warpbench info FOLDER`
    /// lists them).
    #[arg(long, value_name = "UID")]
    pub fixed_series: Option<String>,
    /// The frame of a 4-D moving file to read, from 0.
    #[arg(long, value_name = "N", conflicts_with = "moving_series")]
    pub moving_frame: Option<usize>,
    /// The series to read from a moving DICOM folder of several, by its SeriesInstanceUID.
    #[arg(long, value_name = "UID")]
    pub moving_series: Option<String>,
}

impl PartArgs {
    /// The fixed and the moving volume's part, where one was chosen.
    #[must_use]
    pub fn parts(&self) -> [Option<Part>; 2] {
        let part = |frame: Option<usize>, series: &Option<String>| {
            frame.map(Part::Frame).or_else(|| series.clone().map(Part::Series))
        };
        [part(self.fixed_frame, &self.fixed_series), part(self.moving_frame, &self.moving_series)]
    }

    /// These choices, with `defaults`' part (fixed, moving) for a side that made none.
    #[must_use]
    pub fn or(self, defaults: [Option<Part>; 2]) -> Self {
        let [fixed, moving] = self.parts();
        let [default_fixed, default_moving] = defaults;
        let [(fixed_frame, fixed_series), (moving_frame, moving_series)] =
            [fixed.or(default_fixed), moving.or(default_moving)].map(|part| match part {
                None => (None, None),
                Some(Part::Frame(n)) => (Some(n), None),
                Some(Part::Series(uid)) => (None, Some(uid)),
            });
        Self { fixed_frame, fixed_series, moving_frame, moving_series }
    }
}

/// For `#[command(mut_args(…))]` where `--fixed` and `--moving` are the only source of the volumes (the window's
/// command line): a frame or series chosen needs its volume.
#[must_use]
pub fn parts_need_volumes(arg: clap::Arg) -> clap::Arg {
    match arg.get_id().as_str() {
        "fixed_frame" | "fixed_series" => arg.requires("fixed"),
        "moving_frame" | "moving_series" => arg.requires("moving"),
        _ => arg,
    }
}

/// The landmarks and the warp around them, shared by `warp`, `field`, `render`, `points`, `transform` and `suggest`.
#[derive(Clone, Debug, clap::Args)]
pub struct PairArgs {
    /// A window session (.warpbench.json): its landmark pairs, its warp method and its brush strokes, instead of
    /// --landmarks and the method flags.
    #[arg(long, conflicts_with_all = ["landmarks", "moving_points", "fixed_points", "method", "stiffness", "levels"])]
    pub session: Option<PathBuf>,
    /// Landmark pairs: BigWarp CSV or BigWarp JSON (.json, also a BigWarp settings file), moving then fixed, LPS mm.
    #[arg(long)]
    pub landmarks: Option<PathBuf>,
    /// Slicer point list (.mrk.json or .fcsv) of the moving points; with --fixed-points.
    #[arg(long)]
    pub moving_points: Option<PathBuf>,
    /// Slicer point list of the fixed points, matched to --moving-points by order.
    #[arg(long)]
    pub fixed_points: Option<PathBuf>,
    #[command(flatten)]
    pub method: MethodArgs,
    /// A starting transform under the landmark warp: an ITK affine .tfm, the same affine as ANTs' .mat (e.g.
    /// antsRegistration's 0GenericAffine.mat), an ITK .h5 of affines, or elastix's linear TransformParameters.N.txt,
    /// mapping fixed points to moving points (LPS mm), as `warpbench align` writes it; or FSL's FLIRT matrix (flirt
    /// -omat), read against --fixed as its -ref and --moving as its -in; or AFNI's .aff12.1D (--fixed its base,
    /// --moving its source, neither oblique); or FreeSurfer's .lta (mri_robust_register, bbregister), whose volume
    /// info must name --fixed or --moving. The landmark warp refines it; with fewer pairs than the method needs, it
    /// alone is the warp.
    #[arg(long, value_name = "TFM", conflicts_with = "session")]
    pub initial: Option<PathBuf>,
    /// A displacement field under the landmark warp, in mm: ITK's or ANTs' NIfTI, Slicer's NRRD, MetaImage, an ITK
    /// .h5 holding one, or elastix's deformationField (e.g. a registration the landmarks correct). It maps fixed
    /// points first and --initial after it, as antsApplyTransforms -t FIELD -t TFM does.
    #[arg(long, value_name = "FIELD", conflicts_with = "session")]
    pub initial_field: Option<PathBuf>,
    /// How --initial-field is read: auto (by its content) or learn2reg (Learn2Reg's steps from fixed voxels to moving
    /// voxels, .npz or an (X, Y, Z, 3) NIfTI, which says nothing of its units otherwise).
    #[arg(long, value_name = "FORMAT", value_enum, default_value = "auto", requires = "initial_field")]
    pub initial_field_format: crate::project::field_file::FieldReadFormat,
}

/// `--method` with its parameters, parsed once into a [`warpbench_solver::method::Method`]
/// ([`crate::inputs::MethodChoice`]).
#[derive(Clone, Copy, Debug, PartialEq, clap::Args)]
pub struct MethodArgs {
    /// The warp.
    #[arg(long, value_enum, default_value_t)]
    pub method: MethodKind,
    /// TPS stiffness λ ≥ 0 (0 interpolates the landmarks), or auto: the λ under which the pairs are most likely
    /// (generalised maximum likelihood).
    #[arg(long, default_value_t)]
    pub stiffness: Stiffness,
    /// Hierarchical B-spline levels.
    #[arg(long)]
    pub levels: Option<usize>,
}

/// The flags of a subcommand that writes files and reports what it did: shared by `warp`, `field`, `points`,
/// `transform`, `landmarks`, `align` and `suggest`.
#[derive(Clone, Copy, Debug, clap::Args)]
pub struct ReportArgs {
    /// Print a JSON report to stdout (its schema is in docs/cli.md).
    #[arg(long)]
    pub json: bool,
    /// Overwrite existing outputs.
    #[arg(long)]
    pub force: bool,
    /// No progress bars or messages.
    #[arg(long, short)]
    pub quiet: bool,
}

/// How `render` draws its frame: the blend, the looks, the camera or the slice, the procedural deformation and the
/// glyphs.
#[derive(Clone, Copy, Debug, clap::Args)]
pub struct RenderSettingsArgs {
    /// How the fixed and the deformed moving volume combine.
    #[arg(long, value_enum, default_value_t)]
    pub blend: Blend,
    /// Moving weight of the mix blend (0..1).
    #[arg(long, default_value_t = 0.5)]
    pub mix_weight: f32,
    /// Checkerboard cell size (mm).
    #[arg(long, default_value_t = 12.0)]
    pub checker_mm: f32,
    /// Fixed volume preset (default: from the data).
    #[arg(long, value_enum)]
    pub preset: Option<Preset>,
    /// Moving volume preset (default: from the data).
    #[arg(long, value_enum)]
    pub moving_preset: Option<Preset>,
    /// Lighting: none, dvr (shaded volume rendering) or iso (first surface).
    #[arg(long, value_enum, default_value_t)]
    pub shading: Shading,
    /// Camera as az,el or az,el,dist: degrees about the superior axis and above the horizon, distance in mm.
    #[arg(long)]
    pub camera: Option<CameraSpec>,
    /// Perspective projection (default orthographic).
    #[arg(long)]
    pub perspective: bool,
    /// Image size WxH (3-D view; a slice has its grid's size).
    #[arg(long, default_value = "512x512", value_parser = parse_size)]
    pub size: (u32, u32),
    /// Samples per voxel along each ray.
    #[arg(long, default_value_t = 1.0)]
    pub samples_per_voxel: f32,
    /// A slice of the fixed grid instead of the 3-D view: axial, coronal or sagittal, optionally with :POS in mm
    /// (e.g. axial:40; default the centre).
    #[arg(long)]
    pub slice: Option<SliceSpec>,
    /// Deform the moving volume in the shader: eval's synthetic warp of this kind (sine, twist, bend, bump) over the
    /// moving volume's box, or a shift; read at p(u(x)) after the landmark warp u. --moving V --fixed V shows the
    /// volume eval --kind K --amplitude-mm A --seed S tests.
    #[arg(long, value_enum)]
    pub procedural: Option<ProceduralKind>,
    /// The procedural deformation's largest displacement over the moving volume's box (mm), as eval's --amplitude-mm.
    #[arg(long, default_value_t = 5.0, requires = "procedural")]
    pub procedural_amplitude_mm: f64,
    /// The procedural deformation's seed, as eval's --seed.
    #[arg(long, default_value_t = 1, requires = "procedural")]
    pub procedural_seed: u64,
    /// Leave out the landmark glyphs.
    #[arg(long)]
    pub no_glyphs: bool,
}

impl RenderSettingsArgs {
    /// The moving volume's procedural deformation: `--procedural` with its amplitude and seed.
    #[must_use]
    pub fn procedural_spec(&self) -> Option<ProceduralSpec> {
        self.procedural.map(|kind| ProceduralSpec {
            kind,
            amplitude_mm: self.procedural_amplitude_mm,
            seed: self.procedural_seed,
        })
    }
}

/// Which slice of the fixed grid `--slice` asks for.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum SliceSpec {
    Axial(f64),
    Coronal(f64),
    Sagittal(f64),
}

impl std::str::FromStr for SliceSpec {
    type Err = String;
    /// `axial:POS`, `coronal:POS` or `sagittal:POS`, POS in mm along S, P or L; a bare name is the centre.
    fn from_str(s: &str) -> Result<Self, String> {
        let (name, pos) = s.split_once(':').unwrap_or((s, "nan"));
        let pos: f64 = if pos == "nan" {
            f64::NAN
        } else {
            pos.parse().map_err(|_| format!("slice position {pos:?} is not a number (mm)"))?
        };
        match name {
            "axial" => Ok(Self::Axial(pos)),
            "coronal" => Ok(Self::Coronal(pos)),
            "sagittal" => Ok(Self::Sagittal(pos)),
            _ => Err(format!("slice {name:?}: use axial, coronal or sagittal, optionally with :POS in mm")),
        }
    }
}

/// `--camera az,el[,dist]`: azimuth and elevation in degrees, distance from the target in mm.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CameraSpec {
    pub azimuth_deg: f32,
    pub elevation_deg: f32,
    pub distance_mm: Option<f32>,
}

impl std::str::FromStr for CameraSpec {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        let parts: Vec<f32> = s
            .split(',')
            .map(|p| p.trim().parse::<f32>().map_err(|_| format!("camera value {p:?} is not a number")))
            .collect::<Result<_, _>>()?;
        match parts[..] {
            [az, el] if az.is_finite() && el.is_finite() => {
                Ok(Self { azimuth_deg: az, elevation_deg: el, distance_mm: None })
            }
            [az, el, d] if az.is_finite() && el.is_finite() && d.is_finite() && d > 0.0 => {
                Ok(Self { azimuth_deg: az, elevation_deg: el, distance_mm: Some(d) })
            }
            _ => Err(format!("--camera {s:?}: give az,el or az,el,dist (degrees, degrees, mm > 0)")),
        }
    }
}

/// `--size WxH`.
pub fn parse_size(s: &str) -> Result<(u32, u32), String> {
    let (w, h) = s.split_once(['x', 'X']).ok_or_else(|| format!("--size {s:?}: use WxH, e.g. 512x512"))?;
    let parse = |v: &str| v.parse::<u32>().ok().filter(|n| (1..=8192).contains(n));
    match (parse(w), parse(h)) {
        (Some(w), Some(h)) => Ok((w, h)),
        _ => Err(format!("--size {s:?}: width and height must be 1..8192")),
    }
}
