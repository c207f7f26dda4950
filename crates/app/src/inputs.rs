//! What every pair subcommand (`warp`, `field`, `render`, `points`, `transform`, `suggest`) reads first: the fixed
//! and moving volumes, the landmark pairs, and the warp fitted on them.
//!
//! The shared argument groups ([`crate::args`]) are parsed here once into these types: [`PairArgs`] into a
//! [`LandmarkWarp`] (the landmarks, if any, and the warp around them; a session is read once, pairs and all), its
//! [`MethodArgs`] into a [`MethodChoice`], and with the volume pair into [`PairInputs`] where landmarks are required.
//! A landmark file is read at most once ([`Landmarks`]): `--stiffness auto` chooses λ on the pairs the fit then takes.
//!
//! Landmarks are checked against the volumes before anything is fitted: a pair whose moving point lies outside the
//! moving volume's box (of voxel edges), or whose fixed point lies outside the fixed volume's, is bad input, named by
//! its index (1-based, in file order) and name.
//!
//! The fit ([`crate::fit`]) then checks the pairs themselves ([`warpbench_solver::pairs`], the same rules for every
//! method): its errors and warnings name the landmark file and number the pairs as the file does (1-based, inactive
//! and incomplete pairs counted), not as the fit saw them ([`Correspondences::file_number`]).
//!
//! Errors are `anyhow` errors that name the file and the problem; every one is about the input (the output checks,
//! [`check_output`] and [`OutputFile::check`], included), so the subcommands exit with 2 on them.

use std::cell::OnceCell;
use std::path::{Path, PathBuf};

use anyhow::{Result, anyhow};
use warpbench_io::geometry::{Lps, Point3, Space};
use warpbench_io::landmarks::{self, LandmarkPair};
use warpbench_io::{LoadOptions, Volume};
use warpbench_solver::brush::BrushStroke;
use warpbench_solver::bspline::BSplineParams;
use warpbench_solver::method::Method;
use warpbench_solver::spaces::{Aabb, Fixed, Moving, as_fixed, as_moving};

use crate::args::{MethodArgs, PairArgs, PartArgs, VolumePairArgs};
use crate::progress::Bar;
use crate::project::document::VolumeSource;
use crate::project::field_file::{FieldFile, FieldReadFormat};
use crate::settings::{MethodKind, Stiffness};

/// Loads the fixed and the moving volume of `volumes` ([`load_volume`], each its `--fixed-frame`/`--fixed-series`
/// part). With `quiet` they load on two threads: inflating and decoding a file is one thread's work, so the two take
/// about the time of the slower one (the 176×256×256 head MRI of `data-scripts/compare_itk_warp.py` loaded as both,
/// on a busy 2-core machine: 0.76 s, against 1.03 s one after the other). With progress bars they load one after the
/// other, so that the bars do not interleave. Errors come in the same order either way: the fixed volume's first.
pub fn load_pair(volumes: &VolumePair, quiet: bool) -> Result<(Volume, Volume)> {
    let [fixed_part, moving_part] = volumes.parts.parts();
    let fixed = VolumeArg { path: &volumes.fixed, part: fixed_part.as_ref(), role: Role::Fixed };
    let moving = VolumeArg { path: &volumes.moving, part: moving_part.as_ref(), role: Role::Moving };
    let (fixed, moving) = if quiet {
        std::thread::scope(|s| {
            let moving = s.spawn(|| load_volume(&moving, true));
            let fixed = load_volume(&fixed, true);
            (fixed, moving.join().unwrap_or_else(|panic| std::panic::resume_unwind(panic)))
        })
    } else {
        (load_volume(&fixed, false), load_volume(&moving, false))
    };
    Ok((fixed?, moving?))
}

/// Which of a command's volumes a file is, for the option that would choose its frame or series in a message.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Role {
    /// `--fixed` (`--fixed-frame`, `--fixed-series`).
    Fixed,
    /// `--moving` (`--moving-frame`, `--moving-series`).
    Moving,
    /// A volume without such options (a mask, a reference grid, `eval`'s volume).
    Other,
}

impl Role {
    /// The option's prefix: `fixed`, `moving`.
    fn option(self) -> Option<&'static str> {
        match self {
            Self::Fixed => Some("fixed"),
            Self::Moving => Some("moving"),
            Self::Other => None,
        }
    }
}

/// A volume a command reads: its file, the part of it that was chosen, and which of the command's volumes it is.
#[derive(Clone, Copy, Debug)]
pub struct VolumeArg<'a> {
    pub path: &'a Path,
    pub part: Option<&'a warpbench_io::Part>,
    pub role: Role,
}

impl<'a> VolumeArg<'a> {
    /// A volume read whole, without a frame or series option (a mask, a reference grid).
    #[must_use]
    pub fn other(path: &'a Path) -> Self {
        Self { path, part: None, role: Role::Other }
    }
}

/// Loads a volume (any format `io` reads, the part chosen), with a progress bar unless `quiet`. A file of several
/// frames or a folder of several series, with none chosen, is refused with the option that chooses one.
pub fn load_volume(volume: &VolumeArg<'_>, quiet: bool) -> Result<Volume> {
    let path = volume.path;
    let mut bar = Bar::new(quiet);
    let loaded = LoadOptions::new().part(volume.part).progress(|p| bar.update(p)).open(path);
    bar.finish();
    let volume = loaded.map_err(|e| match (&e.kind, volume.role.option()) {
        (&warpbench_io::ErrorKind::FrameRequired { frames }, Some(option)) => anyhow!(
            "{}: {}: this command reads one 3-D volume; choose one with --{option}-frame N (N from 0 to {})",
            path.display(),
            frames_of(path, frames),
            frames.saturating_sub(1)
        ),
        (warpbench_io::ErrorKind::MultipleSeries(_), Some(option)) => {
            anyhow!("{e}\nchoose one with --{option}-series UID")
        }
        // A volume without --frame: say what to do here.
        (&warpbench_io::ErrorKind::FrameRequired { frames }, None)
            if warpbench_io::afni_dataset::has_afni_name(path) =>
        {
            anyhow!(
                "{}: {}: this command reads one 3-D volume; name one as AFNI's programs do, '{}[N]' (N from 0 \
                 to {}; quoted for the shell)",
                path.display(),
                frames_of(path, frames),
                path.display(),
                frames.saturating_sub(1)
            )
        }
        (&warpbench_io::ErrorKind::FrameRequired { frames }, None) => anyhow!(
            "{}: {}: this command reads one 3-D volume; save one frame as a file of its own (`warpbench info \
             --frame N` shows frame N, 0 to {})",
            path.display(),
            frames_of(path, frames),
            frames.saturating_sub(1)
        ),
        _ => anyhow::Error::from(e),
    })?;
    if !quiet {
        for w in &volume.metadata.warnings {
            eprintln!("warpbench: warning: {}: {w}", path.display());
        }
    }
    Ok(volume)
}

/// Whether `a` and `b` name one file: the same path once resolved (the same text where either cannot be).
fn same_file(a: &Path, b: &Path) -> bool {
    match (std::fs::canonicalize(a), std::fs::canonicalize(b)) {
        (Ok(a), Ok(b)) => a == b,
        _ => a == b,
    }
}

/// A part in words: "frame 3", "series 1.2.840.…".
fn describe_part(part: &warpbench_io::Part) -> String {
    match part {
        warpbench_io::Part::Frame(n) => format!("frame {n}"),
        warpbench_io::Part::Series(uid) => format!("series {uid}"),
    }
}

/// What a file of `frames` frames is, in its own format's words: "an AFNI dataset of 3 sub-bricks", "4-D file with 5
/// frames".
fn frames_of(path: &Path, frames: usize) -> String {
    if warpbench_io::afni_dataset::has_afni_name(path) {
        format!("an AFNI dataset of {frames} sub-bricks")
    } else {
        format!("4-D file with {frames} frames")
    }
}

/// Where the landmark pairs come from.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum LandmarkSource {
    /// One file of pairs: BigWarp CSV or BigWarp JSON, told apart by content.
    Pairs(PathBuf),
    /// Two one-side point lists, Slicer (`.mrk.json` or `.fcsv`) or elastix `point` files, moving then fixed, matched
    /// by order.
    SlicerPair { moving: PathBuf, fixed: PathBuf },
    /// A window session's pairs (`--session`).
    Session(PathBuf),
}

impl LandmarkSource {
    /// From the CLI's `--landmarks L` or `--moving-points M --fixed-points F`.
    pub fn from_args(
        landmarks: Option<PathBuf>,
        moving_points: Option<PathBuf>,
        fixed_points: Option<PathBuf>,
    ) -> Result<Option<Self>> {
        match (landmarks, moving_points, fixed_points) {
            (None, None, None) => Ok(None),
            (Some(l), None, None) => Ok(Some(Self::Pairs(l))),
            (None, Some(moving), Some(fixed)) => Ok(Some(Self::SlicerPair { moving, fixed })),
            (Some(_), _, _) => Err(anyhow!("give either --landmarks or --moving-points with --fixed-points, not both")),
            _ => Err(anyhow!("--moving-points and --fixed-points go together")),
        }
    }

    /// The paths, for messages and for the refuse-to-overwrite check.
    #[must_use]
    pub fn paths(&self) -> Vec<&Path> {
        match self {
            Self::Pairs(p) | Self::Session(p) => vec![p],
            Self::SlicerPair { moving, fixed } => vec![moving, fixed],
        }
    }

    /// The paths joined by ` + `, as messages name the pairs' origin.
    #[must_use]
    pub fn describe(&self) -> String {
        self.paths().iter().map(|p| p.display().to_string()).collect::<Vec<_>>().join(" + ")
    }

    /// Reads the pairs. A single `.mrk.json`/`.fcsv` or elastix point file is refused with a hint: it holds one side
    /// only.
    pub fn read(&self) -> Result<Vec<LandmarkPair>> {
        match self {
            Self::Pairs(path) => {
                let format = landmarks::detect_landmark_file(path)?;
                if format.holds_pairs() {
                    Ok(landmarks::read_landmark_pairs(path)?)
                } else {
                    let what = if format == landmarks::LandmarkFileFormat::ElastixPoints {
                        "an elastix point file"
                    } else {
                        "a Slicer point list"
                    };
                    Err(anyhow!(
                        "{}: {what} holds one side of the pairs; give the moving and the fixed list with \
                         --moving-points and --fixed-points",
                        path.display()
                    ))
                }
            }
            Self::SlicerPair { moving, fixed } => Ok(landmarks::read_slicer_pair(moving, fixed)?),
            Self::Session(path) => Ok(crate::project::session::load(path)?.document.pairs),
        }
    }
}

/// A landmark source and its pairs, read at most once: on the first [`Landmarks::pairs`] (`--stiffness auto` reads
/// them to choose λ before any volume is loaded, and the fit takes the same pairs), or with a session.
#[derive(Clone, Debug)]
pub struct Landmarks {
    pub source: LandmarkSource,
    pairs: OnceCell<Vec<LandmarkPair>>,
}

impl Landmarks {
    /// The pairs of `source`, not read yet.
    #[must_use]
    pub fn new(source: LandmarkSource) -> Self {
        Self { source, pairs: OnceCell::new() }
    }

    /// The pairs of `source`, already read (a session's, read with its warp).
    #[must_use]
    pub fn read_from(source: LandmarkSource, pairs: Vec<LandmarkPair>) -> Self {
        Self { source, pairs: OnceCell::from(pairs) }
    }

    /// The pairs as the file holds them ([`LandmarkSource::read`] the first time).
    pub fn pairs(&self) -> Result<&[LandmarkPair]> {
        if let Some(pairs) = self.pairs.get() {
            return Ok(pairs);
        }
        let pairs = self.source.read()?;
        Ok(self.pairs.get_or_init(|| pairs))
    }

    /// The paths joined by ` + `, as messages name the pairs' origin ([`LandmarkSource::describe`]).
    #[must_use]
    pub fn describe(&self) -> String {
        self.source.describe()
    }
}

/// The warp method the arguments name ([`MethodArgs`]), parsed: a method, or the TPS whose λ the pairs choose.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum MethodChoice {
    Given(Method),
    /// `--stiffness auto` with the `--method` given: the TPS whose λ the pull-back's pairs make most likely
    /// (generalised maximum likelihood, [`warpbench_solver::stiffness`]; fixed → moving, the active pairs with both
    /// points), chosen when they are read ([`MethodChoice::method`]). Another method is refused there, where a method is needed (`suggest` without
    /// landmarks needs none).
    Auto(MethodKind),
}

impl From<&MethodArgs> for MethodChoice {
    /// A stiffness given as a number was checked where it was parsed ([`Stiffness`]'s `FromStr`).
    fn from(args: &MethodArgs) -> Self {
        match args.stiffness {
            Stiffness::Value(stiffness) => Self::Given(args.method.method(stiffness, levels_or_default(args.levels))),
            Stiffness::Auto => Self::Auto(args.method),
        }
    }
}

impl MethodChoice {
    /// The method. [`MethodChoice::Auto`] reads the pairs of `landmarks` (kept there for the fit) and names the λ
    /// chosen (`tps(λ=…)`) wherever the method is reported.
    pub fn method(self, landmarks: Option<&Landmarks>) -> Result<Method> {
        let kind = match self {
            Self::Given(method) => return Ok(method),
            Self::Auto(kind) => kind,
        };
        if kind != MethodKind::Tps {
            return Err(anyhow!("--stiffness auto chooses the TPS's λ: it needs --method tps, not {kind}"));
        }
        let landmarks = landmarks.ok_or_else(|| anyhow!("--stiffness auto needs landmark pairs to choose from"))?;
        let (fixed, moving): (Vec<Point3<Fixed>>, Vec<Point3<Moving>>) = landmarks
            .pairs()?
            .iter()
            .filter(|p| p.active)
            .filter_map(|p| Some((as_fixed(p.fixed?), as_moving(p.moving?))))
            .unzip();
        let choice = warpbench_solver::stiffness::choose_stiffness(&fixed, &moving)
            .map_err(|e| anyhow!("{}: --stiffness auto: {e}", landmarks.describe()))?;
        Ok(Method::Tps { stiffness: choice.lambda })
    }
}

/// The warp [`PairArgs`] ask for around the landmarks: the method, and the warp stack's other layers (a session's
/// brush strokes on top, a starting transform and a displacement field under the landmark fit).
#[derive(Clone, Debug, PartialEq)]
pub struct PairWarp {
    pub method: MethodChoice,
    /// Brush strokes on top of the landmark warp (a session's, [`crate::brushed`]).
    pub brush: Vec<BrushStroke>,
    /// The starting transform's file under the landmark warp (`--initial`, read when the warp is fitted,
    /// [`crate::start::Start::read`]).
    pub initial: Option<PathBuf>,
    /// A session's starting transform (its Auto-align), read with the session.
    pub session_start: Option<Box<crate::start::Start>>,
    /// The displacement field under the landmark fit: `--initial-field`'s, or a session's (one chosen in the window,
    /// or Refine by intensities'), read when the warp is fitted ([`PairWarp::field`]).
    pub base_field: Option<BaseField>,
}

/// Where the displacement field under the landmark fit comes from.
#[derive(Clone, Debug, PartialEq)]
pub enum BaseField {
    /// `--initial-field`, read as `--initial-field-format` says, against the command's volumes, as the window reads a
    /// field chosen with them open (a Learn2Reg field's voxel steps between their grids).
    Given { path: PathBuf, format: FieldReadFormat },
    /// A session's, with the grids recorded when it was chosen (a Learn2Reg field without them is refused).
    Session(FieldFile),
}

impl BaseField {
    /// The field's file.
    #[must_use]
    pub fn path(&self) -> &Path {
        match self {
            Self::Given { path, .. } => path,
            Self::Session(file) => &file.path,
        }
    }
}

impl PairWarp {
    /// The starting transform under the landmark warp, read (`None` without `--initial` or a session's); a FLIRT or
    /// AFNI matrix or an LTA against `fixed` and `moving`.
    pub fn start(&self, fixed: &Volume, moving: &Volume) -> Result<Option<crate::start::Start>> {
        crate::start::resolve(self.session_start.as_deref(), self.initial.as_deref(), fixed, moving)
    }

    /// Reads `--initial`'s file once before any volume is loaded, so one that cannot be read is refused first; what
    /// it holds is read again with the volumes ([`Self::start`]).
    pub fn check_start(&self) -> Result<()> {
        self.initial.as_deref().map(crate::start::StartFile::read).transpose().map(|_| ())
    }

    /// The fewest pairs a fit of `method` needs on this warp: none over a starting transform or a field (the base
    /// alone is the warp then), the method's own otherwise.
    #[must_use]
    pub fn min_pairs(&self, method: &Method) -> usize {
        let base = self.initial.is_some() || self.session_start.is_some() || self.base_field.is_some();
        if base { 0 } else { method.needs().min_pairs }
    }

    /// The displacement field under the landmark fit, read (`None` without one) against the command's volumes
    /// ([`BaseField`]). Errors name the file.
    pub fn field(
        &self,
        fixed: &Volume,
        moving: &Volume,
    ) -> Result<Option<std::sync::Arc<crate::project::stack::FieldLayer>>> {
        let layer = match &self.base_field {
            None => return Ok(None),
            Some(BaseField::Given { path, format }) => FieldFile::chosen(path.clone(), *format, fixed, moving)?.layer(),
            Some(BaseField::Session(file)) => file.layer(),
        };
        Ok(Some(std::sync::Arc::new(layer?)))
    }

    /// The stack's layers around the landmark fit: the starting transform, the field (read against `fixed` and
    /// `moving`, as [`Self::field`]) and `brushed` on top.
    pub fn layers(
        &self,
        brushed: Option<crate::brushed::Brushed>,
        fixed: &Volume,
        moving: &Volume,
    ) -> Result<crate::project::stack::Layers> {
        let mut layers = crate::project::stack::Layers::new(self.start(fixed, moving)?, brushed);
        layers.field = self.field(fixed, moving)?;
        Ok(layers)
    }
}

/// Prints what the reader of the displacement field under the fit assumed ([`FieldLayer::warnings`]) on stderr, unless
/// `quiet`, as a volume's reader warnings are printed.
///
/// [`FieldLayer::warnings`]: crate::project::stack::FieldLayer::warnings
pub fn note_field_warnings(field: Option<&crate::project::stack::FieldLayer>, quiet: bool) {
    if quiet {
        return;
    }
    for w in field.map(|f| f.warnings.as_slice()).unwrap_or_default() {
        eprintln!("warpbench: warning: {w}");
    }
}

/// [`PairArgs`] parsed once: the landmarks, if any were given, and the warp around them.
#[derive(Clone, Debug)]
pub struct LandmarkWarp {
    pub landmarks: Option<Landmarks>,
    pub warp: PairWarp,
    /// A session's choices for Refine by intensities, which `register --session` takes unless told otherwise.
    pub session_refine: Option<SessionRefine>,
    /// With `--session`, the session's file and the volumes it read.
    pub session: Option<SessionVolumes>,
}

/// A session's file and the volumes the window read with it: what `--fixed` and `--moving` default to.
#[derive(Clone, Debug, PartialEq)]
pub struct SessionVolumes {
    pub path: PathBuf,
    /// Fixed, then moving, with the frame or series of each; `None`s for the demo pair.
    pub sources: [Option<VolumeSource>; 2],
}

/// The two volumes a pair subcommand reads, as [`LandmarkWarp::volumes`] resolves `--fixed`, `--moving` and
/// `--session`: the files, and the frame or series of each.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct VolumePair {
    pub fixed: PathBuf,
    pub moving: PathBuf,
    pub parts: PartArgs,
}

impl VolumePair {
    /// `--fixed` and `--moving` of a subcommand without `--session`, where the argument parser requires both.
    ///
    /// # Errors
    /// Either left out.
    pub fn given(args: VolumePairArgs) -> Result<Self> {
        match (args.fixed, args.moving) {
            (Some(fixed), Some(moving)) => Ok(Self { fixed, moving, parts: args.parts }),
            _ => Err(anyhow!("give --fixed and --moving")),
        }
    }
}

/// What a session chose for Refine by intensities.
#[derive(Clone, Debug, PartialEq)]
pub struct SessionRefine {
    pub metric: crate::settings::Metric,
    pub fixed_mask: Option<PathBuf>,
    pub moving_mask: Option<PathBuf>,
}

impl TryFrom<PairArgs> for LandmarkWarp {
    type Error = anyhow::Error;

    /// The landmark files and the method flags, or with `--session` the session's pairs, method, brush strokes and
    /// starting transform (the session is read here, once, so one that cannot be read is refused before any volume
    /// is loaded).
    fn try_from(args: PairArgs) -> Result<Self> {
        let Some(path) = args.session else {
            let source = LandmarkSource::from_args(args.landmarks, args.moving_points, args.fixed_points)?;
            return Ok(Self {
                landmarks: source.map(Landmarks::new),
                warp: PairWarp {
                    method: MethodChoice::from(&args.method),
                    brush: Vec::new(),
                    initial: args.initial,
                    session_start: None,
                    base_field: args
                        .initial_field
                        .map(|path| BaseField::Given { path, format: args.initial_field_format }),
                },
                session_refine: None,
                session: None,
            });
        };
        let session = crate::project::session::load(&path)?;
        let session_start = session
            .document
            .start
            .as_ref()
            .map(|s| s.start().map(Box::new).map_err(|e| anyhow!("{}: {e:#}", path.display())))
            .transpose()?;
        let s = &session.document.settings;
        let method = checked_method(s.method, s.stiffness, Some(s.bspline_levels))?;
        let document = session.document;
        let session_volumes = SessionVolumes { path: path.clone(), sources: document.sources() };
        let session_refine = Some(SessionRefine {
            metric: document.settings.refine_metric,
            fixed_mask: document.fixed_mask,
            moving_mask: document.moving_mask,
        });
        Ok(Self {
            session_refine,
            session: Some(session_volumes),
            landmarks: Some(Landmarks::read_from(LandmarkSource::Session(path), document.pairs)),
            warp: PairWarp {
                method: MethodChoice::Given(method),
                brush: document.brush,
                initial: None,
                session_start,
                base_field: document.field.map(BaseField::Session),
            },
        })
    }
}

impl LandmarkWarp {
    /// The landmarks, which the subcommand needs, and the warp around them.
    pub fn require(self) -> Result<(Landmarks, PairWarp)> {
        let landmarks = self
            .landmarks
            .ok_or_else(|| anyhow!("give --landmarks, --moving-points with --fixed-points, or --session"))?;
        Ok((landmarks, self.warp))
    }

    /// The files and parts to read for the command line's `--fixed` and `--moving` (`given`; either may be left out)
    /// and their `parts`. With `--session`, a side left out reads the session's file, and its frame or series unless
    /// the command line chose one; a side that names the session's file (by any path) and chooses no part reads the
    /// session's part. What the session chose is said on stderr, unless `quiet`; a side left out without a session
    /// stays `None`.
    ///
    /// # Errors
    /// A side left out with a session of the demo pair, which has no files; a frame or series chosen for a side that
    /// has no file.
    pub fn resolve_volumes(
        &self,
        given: [Option<PathBuf>; 2],
        parts: PartArgs,
        quiet: bool,
    ) -> Result<([Option<PathBuf>; 2], PartArgs)> {
        let chosen = parts.parts();
        let mut paths = given;
        let mut defaults = [None, None];
        for (side, name) in ["fixed", "moving"].into_iter().enumerate() {
            let Some(session) = &self.session else { continue };
            let Some(source) = &session.sources[side] else {
                if paths[side].is_none() {
                    return Err(anyhow!(
                        "{}: the session shows the demo pair, which has no files: give --fixed and --moving",
                        session.path.display()
                    ));
                }
                continue;
            };
            let from_session = paths[side].is_none();
            let path = paths[side].get_or_insert_with(|| source.path.clone());
            let part = source
                .part
                .clone()
                .filter(|_| chosen[side].is_none() && (from_session || same_file(path, &source.path)));
            if !quiet && from_session {
                let what = part.as_ref().map(|p| format!(", {}", describe_part(p))).unwrap_or_default();
                eprintln!(
                    "warpbench: {}: the {name} volume is {}{what}, as the session read it (--{name} chooses another)",
                    session.path.display(),
                    path.display()
                );
            } else if let (false, Some(part)) = (quiet, &part) {
                eprintln!(
                    "warpbench: {}: reading {}, as the session did (--{name}-frame or --{name}-series chooses \
                     another)",
                    path.display(),
                    describe_part(part)
                );
            }
            defaults[side] = part;
        }
        for (side, name) in ["fixed", "moving"].into_iter().enumerate() {
            if paths[side].is_none() && chosen[side].is_some() {
                return Err(anyhow!("--{name}-frame and --{name}-series choose a volume of --{name}: give --{name}"));
            }
        }
        Ok((paths, parts.or(defaults)))
    }

    /// The two volumes to read for `args` ([`Self::resolve_volumes`]; without a session the argument parser
    /// requires both).
    ///
    /// # Errors
    /// As [`Self::resolve_volumes`].
    pub fn volumes(&self, args: VolumePairArgs, quiet: bool) -> Result<VolumePair> {
        let (paths, parts) = self.resolve_volumes([args.fixed, args.moving], args.parts, quiet)?;
        VolumePair::given(VolumePairArgs { fixed: paths[0].clone(), moving: paths[1].clone(), parts })
    }

    /// The method ([`MethodChoice::method`] on these landmarks).
    pub fn method(&self) -> Result<Method> {
        self.warp.method.method(self.landmarks.as_ref())
    }

    /// Every input file of the warp: the landmarks', the starting transform's and the field's.
    #[must_use]
    pub fn paths(&self) -> Vec<&Path> {
        let mut paths = self.landmarks.as_ref().map_or_else(Vec::new, |l| l.source.paths());
        paths.extend(self.warp.initial.as_deref());
        paths.extend(self.warp.base_field.as_ref().map(BaseField::path));
        paths
    }
}

/// What the pair subcommands (`warp`, `field`, `points`, `transform`) read: the volume pair, its landmarks, the warp
/// around them, and the grid to sample on when it is not the fixed volume's.
#[derive(Clone, Debug)]
pub struct PairInputs {
    pub volumes: VolumePair,
    pub landmarks: Landmarks,
    pub warp: PairWarp,
    /// The output grid, when not the fixed volume's.
    pub reference: Option<PathBuf>,
}

/// The volumes of [`PairInputs`], loaded.
#[derive(Debug)]
pub struct PairVolumes {
    pub fixed: Volume,
    pub moving: Volume,
    pub reference: Option<Volume>,
}

impl PairInputs {
    /// Parses the arguments once ([`LandmarkWarp`]); landmarks are required. A session's volumes are read where the
    /// command line names none ([`LandmarkWarp::volumes`]).
    pub fn new(volumes: VolumePairArgs, pairs: PairArgs, reference: Option<PathBuf>, quiet: bool) -> Result<Self> {
        let given = LandmarkWarp::try_from(pairs)?;
        let volumes = given.volumes(volumes, quiet)?;
        let (landmarks, warp) = given.require()?;
        Ok(Self { volumes, landmarks, warp, reference })
    }

    /// Every input file, which no output may be.
    #[must_use]
    pub fn paths(&self) -> Vec<&Path> {
        let mut paths: Vec<&Path> = vec![&self.volumes.fixed, &self.volumes.moving];
        paths.extend(self.landmarks.source.paths());
        paths.extend(self.reference.as_deref());
        paths.extend(self.warp.initial.as_deref());
        paths.extend(self.warp.base_field.as_ref().map(BaseField::path));
        paths
    }

    /// The starting transform under the landmark warp, read (`None` without `--initial`); a FLIRT or AFNI matrix or
    /// an LTA against `fixed` and `moving`.
    pub fn start(&self, fixed: &Volume, moving: &Volume) -> Result<Option<crate::start::Start>> {
        self.warp.start(fixed, moving)
    }

    /// The method ([`MethodChoice::method`]; `--stiffness auto` reads the pairs, and [`PairInputs::pairs`] gives
    /// the same ones).
    pub fn method(&self) -> Result<Method> {
        self.warp.method.method(Some(&self.landmarks))
    }

    /// The landmark pairs as read, once ([`Landmarks::pairs`]).
    pub fn pairs(&self) -> Result<&[LandmarkPair]> {
        self.landmarks.pairs()
    }

    /// The brush on top of the landmark warp, inverted (`None` without strokes); errors name the landmark source.
    pub fn brushed(&self) -> Result<Option<crate::brushed::Brushed>> {
        crate::brushed::Brushed::new(&self.warp.brush, &self.landmarks.describe())
    }

    /// What messages call the inputs, and `out`.
    #[must_use]
    pub fn names(&self, out: &Path) -> Names {
        Names {
            moving: self.volumes.moving.display().to_string(),
            landmarks: self.landmarks.describe(),
            out: out.to_owned(),
        }
    }

    /// Loads the fixed, moving and reference volumes ([`load_pair`], then the reference; with progress bars unless
    /// `quiet`).
    pub fn load_volumes(&self, quiet: bool) -> Result<PairVolumes> {
        let (fixed, moving) = load_pair(&self.volumes, quiet)?;
        let reference = self.reference.as_deref().map(|p| load_volume(&VolumeArg::other(p), quiet)).transpose()?;
        Ok(PairVolumes { fixed, moving, reference })
    }
}

/// What the in-memory cores ([`crate::warp::resample`], [`crate::field::displacement_field`]) call their inputs and
/// output in messages: the files' paths on the command line, the window's own names in the window.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Names {
    /// The moving volume, e.g. its path.
    pub moving: String,
    /// Where the landmark pairs come from, e.g. [`LandmarkSource::describe`].
    pub landmarks: String,
    /// The output file, named by errors about the output (a grid too large to allocate).
    pub out: PathBuf,
}

/// The active, complete pairs, typed by space, with their 1-based index and name for messages.
#[derive(Clone, Debug)]
pub struct Correspondences {
    pub moving: Vec<Point3<Moving>>,
    pub fixed: Vec<Point3<Fixed>>,
    /// `(index in the file, 1-based; name)` of each pair kept.
    pub labels: Vec<(usize, String)>,
    /// Where the pairs come from, as messages name it (the files' paths, or the window's name for its table).
    pub origin: String,
}

impl Correspondences {
    /// The file's number (1-based) of the fit's pair `n` (1-based, counting only the pairs kept).
    #[must_use]
    pub fn file_number(&self, n: usize) -> usize {
        n.checked_sub(1).and_then(|i| self.labels.get(i)).map_or(n, |(file_index, _)| *file_index)
    }
}

/// The box of voxel edges of `v` in its LPS space, as an axis-aligned box (the corners' bounds).
#[must_use]
pub fn volume_box<S: Space>(v: &Volume) -> Aabb<S> {
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for corner in 0..8 {
        let idx = std::array::from_fn(|a| if corner >> a & 1 == 0 { -0.5 } else { v.dims[a] as f64 - 0.5 });
        let p = v.lps_from_index.apply_point(Point3::from_array(idx)).coords();
        for a in 0..3 {
            lo[a] = lo[a].min(p[a]);
            hi[a] = hi[a].max(p[a]);
        }
    }
    Aabb::new(Point3::from_array(lo), Point3::from_array(hi))
}

/// Whether `p` lies in the voxel-edge box of `v` (in its index space, so oblique grids are exact).
fn inside(v: &Volume, p: Point3<Lps>) -> bool {
    let Some(index_from_lps) = v.lps_from_index.inverse() else { return false };
    let idx = index_from_lps.apply_point(p).coords();
    (0..3).all(|a| idx[a] >= -0.5 && idx[a] <= v.dims[a] as f64 - 0.5)
}

/// Checks `pairs` against the volumes (module docs) and keeps the active, complete ones. Errors name the source,
/// the pair and the problem; fewer than `min_pairs` complete active pairs is an error too.
pub fn correspondences(
    source: &LandmarkSource,
    pairs: &[LandmarkPair],
    moving: &Volume,
    fixed: &Volume,
    min_pairs: usize,
) -> Result<Correspondences> {
    check_pairs(&source.describe(), pairs, moving, fixed, min_pairs)
}

/// [`correspondences`] for pairs that come from no [`LandmarkSource`] (the window's table): messages name them by
/// `origin` instead of the files' paths.
pub fn check_pairs(
    origin: &str,
    pairs: &[LandmarkPair],
    moving: &Volume,
    fixed: &Volume,
    min_pairs: usize,
) -> Result<Correspondences> {
    collect_pairs(origin, pairs, Some((moving, fixed)), min_pairs)
}

/// [`check_pairs`], with the volumes' boxes checked only when `within` (moving, fixed) is given: the Python
/// package fits pairs with no volumes at hand.
pub fn collect_pairs(
    origin: &str,
    pairs: &[LandmarkPair],
    within: Option<(&Volume, &Volume)>,
    min_pairs: usize,
) -> Result<Correspondences> {
    let mut out =
        Correspondences { moving: Vec::new(), fixed: Vec::new(), labels: Vec::new(), origin: origin.to_owned() };
    let bad = |i: usize, pair: &LandmarkPair, what: &str| {
        let name = if pair.name.is_empty() { String::new() } else { format!(" ({})", pair.name) };
        anyhow!("{origin}: landmark {}{name} {what}", i + 1)
    };
    for (i, pair) in pairs.iter().enumerate() {
        if !pair.active {
            continue;
        }
        let (Some(p), Some(q)) = (pair.moving, pair.fixed) else { continue };
        if !p.coords().iter().chain(&q.coords()).all(|c| c.is_finite()) {
            return Err(bad(i, pair, "has a coordinate that is not a number"));
        }
        if let Some((moving, fixed)) = within {
            if !inside(moving, p) {
                return Err(bad(i, pair, &format!("is outside the moving volume (at {:?} mm LPS)", p.coords())));
            }
            if !inside(fixed, q) {
                return Err(bad(i, pair, &format!("is outside the fixed volume (at {:?} mm LPS)", q.coords())));
            }
        }
        out.moving.push(as_moving(p));
        out.fixed.push(as_fixed(q));
        out.labels.push((i + 1, pair.name.clone()));
    }
    if out.moving.len() < min_pairs {
        return Err(anyhow!(
            "{origin}: {} active pairs with both points; this needs at least {min_pairs}",
            out.moving.len()
        ));
    }
    Ok(out)
}

/// A method of `kind` with a stiffness and levels that no parser has checked (a session's settings, `eval`'s
/// flags): the stiffness must be a number ≥ 0.
pub fn checked_method(kind: MethodKind, stiffness: f64, levels: Option<usize>) -> Result<Method> {
    if !(stiffness.is_finite() && stiffness >= 0.0) {
        return Err(anyhow!("--stiffness {stiffness} must be a number ≥ 0"));
    }
    Ok(kind.method(stiffness, levels_or_default(levels)))
}

/// `--levels`, or the hierarchical B-spline's default.
fn levels_or_default(levels: Option<usize>) -> usize {
    levels.unwrap_or(BSplineParams::default().levels)
}

/// The minimum number of pairs each method needs: the solver's ([`Method::needs`]; 4 for TPS, the hierarchical
/// B-spline and affine, 3 for similarity and rigid).
#[must_use]
pub fn min_pairs(method: &Method) -> usize {
    method.needs().min_pairs
}

/// An output file and whether it may replace an existing one (`--out`, `--force`).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct OutputFile {
    pub path: PathBuf,
    pub force: bool,
}

impl OutputFile {
    /// Refuses to write over an input, or over an existing file without `force`.
    pub fn check(&self, inputs: &[&Path]) -> Result<()> {
        check_output(&self.path, inputs, self.force)
    }
}

/// Refuses to write `out` over an input, over an existing file without `force`, or over a folder other than a Zarr
/// store (which an output named `.zarr` replaces).
pub fn check_output(out: &Path, inputs: &[&Path], force: bool) -> Result<()> {
    let canonical = |p: &Path| std::fs::canonicalize(p).ok();
    if let Some(out_c) = canonical(out)
        && inputs.iter().any(|i| canonical(i).as_ref() == Some(&out_c))
    {
        return Err(anyhow!("{}: refusing to overwrite an input", out.display()));
    }
    if out.exists() && !force {
        return Err(anyhow!("{}: exists; use --force to overwrite it", out.display()));
    }
    // A folder is replaced only when it is a Zarr store and the output is one (`.zarr`); an empty one is written into.
    if out.is_dir() {
        let zarr = warpbench_io::VolumeFileKind::of(out) == Some(warpbench_io::VolumeFileKind::OmeZarr);
        let empty = std::fs::read_dir(out).is_ok_and(|mut d| d.next().is_none());
        if !(zarr && (empty || warpbench_io::ngff::looks_like_zarr(out))) {
            return Err(anyhow!(
                "{}: a folder that warpbench does not replace (only a Zarr store, by an output named .zarr)",
                out.display()
            ));
        }
    }
    Ok(())
}
