//! Command-line arguments that several subcommands share (clap), so each subcommand's module can take them.

use std::path::PathBuf;

use crate::exit::Failure;
use crate::inputs::{LandmarkSource, PairInputs};
use warpbench_solver::brush::BrushStroke;

use crate::settings::{MethodKind, Stiffness};

/// The landmarks and the warp method, shared by `warp`, `field` and `render`.
#[derive(Debug, clap::Args)]
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
    /// The warp.
    #[arg(long, value_enum, default_value_t)]
    pub method: MethodKind,
    /// TPS stiffness λ ≥ 0 (0 interpolates the landmarks), or auto: the λ that minimises the pairs' leave-one-out
    /// error.
    #[arg(long, default_value_t)]
    pub stiffness: Stiffness,
    /// Hierarchical B-spline levels.
    #[arg(long)]
    pub levels: Option<usize>,
    /// A starting transform under the landmark warp: an ITK affine .tfm mapping fixed points to moving points (LPS
    /// mm), as `warpbench align` writes it. The landmark warp refines it; with fewer pairs than the method needs, it
    /// alone is the warp.
    #[arg(long, value_name = "TFM", conflicts_with = "session")]
    pub initial: Option<PathBuf>,
}

/// The flags of a subcommand that writes files and reports what it did: shared by `points`, `transform` and
/// `landmarks`.
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

impl PairArgs {
    /// The landmark source, if any was given (a session's pairs with `--session`).
    pub fn source(&self) -> Result<Option<LandmarkSource>, Failure> {
        if let Some(session) = &self.session {
            return Ok(Some(LandmarkSource::Session(session.clone())));
        }
        LandmarkSource::from_args(self.landmarks.clone(), self.moving_points.clone(), self.fixed_points.clone())
            .map_err(Failure::BadInput)
    }

    /// The warp: the method flags, or with `--session` the session's method and its brush strokes (read here, so a
    /// session that cannot be read is refused before any volume is loaded).
    pub fn warp(&self) -> Result<PairWarp, Failure> {
        let Some(path) = &self.session else {
            return Ok(PairWarp {
                method: self.method,
                stiffness: self.stiffness,
                levels: self.levels,
                brush: Vec::new(),
                initial: self.initial.clone(),
                session_start: None,
            });
        };
        let session = crate::project::session::load(path).map_err(Failure::BadInput)?;
        let session_start = session
            .document
            .start
            .as_ref()
            .map(|s| {
                s.start().map(Box::new).map_err(|e| Failure::BadInput(anyhow::anyhow!("{}: {e:#}", path.display())))
            })
            .transpose()?;
        let s = &session.document.settings;
        Ok(PairWarp {
            method: s.method,
            stiffness: Stiffness::Value(s.stiffness),
            levels: Some(s.bspline_levels),
            brush: session.document.brush,
            initial: None,
            session_start,
        })
    }

    /// The inputs of `warp` and `field`: these landmarks and method with the pair and the reference grid.
    pub fn inputs(self, fixed: PathBuf, moving: PathBuf, reference: Option<PathBuf>) -> Result<PairInputs, Failure> {
        let PairWarp { method, stiffness, levels, brush, initial, session_start } = self.warp()?;
        Ok(PairInputs {
            landmarks: self.required_source()?,
            fixed,
            moving,
            method,
            stiffness,
            levels,
            reference,
            brush,
            initial,
            session_start,
        })
    }

    /// The landmark source, which this subcommand needs.
    pub fn required_source(&self) -> Result<LandmarkSource, Failure> {
        self.source()?.ok_or_else(|| {
            Failure::BadInput(anyhow::anyhow!("give --landmarks, --moving-points with --fixed-points, or --session"))
        })
    }
}

/// The warp [`PairArgs`] ask for: the method and its parameters, and the brush strokes on top (a session's; none
/// from the method flags).
#[derive(Clone, Debug, PartialEq)]
pub struct PairWarp {
    pub method: MethodKind,
    pub stiffness: Stiffness,
    pub levels: Option<usize>,
    pub brush: Vec<BrushStroke>,
    /// The starting transform's file (`--initial`), read when the warp is fitted ([`crate::start::Start::read`]).
    pub initial: Option<PathBuf>,
    /// A session's starting transform (its Auto-align), read with the session.
    pub session_start: Option<Box<crate::start::Start>>,
}
