//! The command-line argument groups that several subcommands share (clap), one per concept, each flattened into the
//! subcommands' own `Args` structs: the volume pair ([`VolumePairArgs`]), the landmarks and the warp around them
//! ([`PairArgs`], with the method, [`MethodArgs`]) and the report flags ([`ReportArgs`]).
//!
//! This module declares flags and parses values only; [`crate::inputs`] turns the groups into the model's types
//! (`TryFrom<PairArgs>`), once, at the start of a subcommand. A subcommand that describes a shared flag in its own
//! words (what its `--fixed` is for) says so with [`help`] in a `#[command(mut_args(…))]` attribute, and its help
//! text, the `--help` page, comes from [`summary`] of one string beside its `Args` struct.

use std::path::PathBuf;

use crate::settings::{MethodKind, Stiffness};

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
/// Each subcommand describes them in its own words ([`help`]).
#[derive(Clone, Debug, PartialEq, Eq, clap::Args)]
pub struct VolumePairArgs {
    /// The fixed volume.
    #[arg(long)]
    pub fixed: PathBuf,
    /// The moving volume.
    #[arg(long)]
    pub moving: PathBuf,
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
    /// A starting transform under the landmark warp: an ITK affine .tfm mapping fixed points to moving points (LPS
    /// mm), as `warpbench align` writes it. The landmark warp refines it; with fewer pairs than the method needs, it
    /// alone is the warp.
    #[arg(long, value_name = "TFM", conflicts_with = "session")]
    pub initial: Option<PathBuf>,
}

/// `--method` with its parameters, parsed once into a [`warpbench_solver::method::Method`]
/// ([`crate::inputs::MethodChoice`]).
#[derive(Clone, Copy, Debug, PartialEq, clap::Args)]
pub struct MethodArgs {
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
